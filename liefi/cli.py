"""The ``liefi`` command: list the paper's experiments, run one, reproduce them all.

::

    liefi --version
    liefi list [-v] [--schemes]
    liefi run SCENE [--rtol R] [--atol A] [--paper] [--dt DT] [--t-final T]
                    [--scheme imex-rk4|euler|heun|rk4|dla|scipy:METHOD]
                    [--gains K | --gains K1,K2,... | --gains name=K,...] [--variant NAME]
                    [--configuration] [--save-every N] [--no-check-stability] [--adaptive]
                    [--json] [--out FILE.png|DIR]
    liefi reproduce [--out DIR] [--only SCENE[,SCENE] | --all] [--t-final-scale S] [--jobs N]
    liefi stability SCENE [--scheme S] [--gains K1,K2,...] [--out FILE.png] [--estimate] [--json]
    liefi bench SCENE|all [--t-final T] [--out DIR] [--scheduler ADDR] [--quick] [--long-horizon T]

``liefi run`` runs one scene with liefi's best method unless told otherwise
(a split scheme, ``imex-rk4``, ``imex-rk6`` or ``imex-rk8``, gains ``auto``, the
order and step chosen for ``--rtol``, default 1e-6: :mod:`liefi.integrator.tolerance`;
``imex-rk4`` with ``--dt``; ``--paper``: the paper's scheme, gains and step) and
reports its error against the exact (or numerical reference) solution, the
drift of every invariant and its CPU time; ``--json`` prints one JSON object,
whose ``method`` entry says which method ran and why.
``liefi reproduce`` is :mod:`liefi.reproduce`.

Errors (unknown scene, variant or scheme, malformed gains, a diverging run, an
output that cannot be written -- checked before any work) print one line
``liefi: error: ...`` on stderr and exit with code 2; an interrupt (Ctrl-C,
SIGINT) prints one line and exits with code 130, SIGTERM (``timeout``, ``kill``,
Slurm, ``docker stop``) the same with code 143 (SIGHUP, a closed terminal: 129), after ``reproduce`` and
``bench`` have stopped their workers and written the summary of what finished;
at any moment, also while liefi still imports numpy or once the output is
written, and within :data:`liefi._signals.GRACE` seconds when it lands in a
compile (:mod:`liefi._signals`).
Nothing here names a scene: what is
particular to one (its figures, whether they need the configuration, its
reproduction runs) is asked of the scene (:class:`liefi.scenes.Scene`).
:func:`main` takes ``argv`` and returns the exit code, so tests call it directly.
matplotlib is imported only when a figure is written.
"""

from __future__ import annotations

import argparse
import math
import re
import sys

from . import __version__
from . import _json
from ._files import probe_writable
from . import scenes as _scenes
from .integrator.run import MAX_RUN_STEPS, check_step_count
from .schemes import IntegrationError
from .schemes import registry as _schemes

#: solve_ivp methods accepted after ``scipy:`` (from the scheme registry)
SCIPY_METHODS = tuple(n.split(":", 1)[1] for n in _schemes.names("scipy"))


class UsageError(Exception):
    """Bad command-line input; the message names the parameter."""


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr (raised, turned into exit 2 by main)."""

    def error(self, message):
        raise UsageError(f"{message} (see '{self.prog} --help')")

    def parse_known_args(self, args=None, namespace=None):
        return super().parse_known_args(self._join_negative(sys.argv[1:] if args is None else args), namespace)

    def _join_negative(self, args):
        """``--dt -1e-3`` -> ``--dt=-1e-3`` for this parser's options that take one value.

        argparse reads ``-1e-3`` as an option (its negative-number pattern has no exponent), so
        the option would get "expected one argument"; joined, the value reaches the option's
        ``type``, which refuses it with a message naming the option (e.g. "dt must be a
        positive number")."""
        out, args = [], list(args)
        i = 0
        while i < len(args):
            a = args[i]
            act = self._option_string_actions.get(a) if isinstance(a, str) and a.startswith("--") else None
            if act is not None and act.nargs is None and i + 1 < len(args) and _NEGATIVE.match(str(args[i + 1])):
                out.append(f"{a}={args[i + 1]}")
                i += 2
                continue
            out.append(a)
            i += 1
        return out


#: a number as a command-line token, exponent included (``1e-3``, ``.5``, ``inf``)
_NUMBER = r"(?:(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|inf|infinity|nan)"
#: a negative number as a command-line token (``-1e-3``, ``-.5``, ``-inf``), or a comma list of numbers that
#: starts with one (``--gains -1,5``): a value, which the option's own check refuses by name
_NEGATIVE = re.compile(rf"^-{_NUMBER}(?:,\s*[-+]?{_NUMBER})*$", re.IGNORECASE)


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------
def gain_names(scene, variant=None, configuration=None):
    """The order of ``--gains K1,K2,...``: the integrator's ``invariant_names``."""
    return tuple(scene.integrator(variant, configuration=configuration).invariant_names)


def default_gains(scene, names):
    """The scene's paper gains expanded to ``{name: k}`` over ``names``."""
    g = scene.gains
    if isinstance(g, dict):
        out = {}
        for k, v in g.items():
            if k == "constraints":
                out.update({n: float(v) for n in names if n.startswith("J_")})
            else:
                out[k] = float(v)
        return {n: out[n] for n in names if n in out}
    return {n: float(g) for n in names}


def parse_gains(text, scene, variant=None, configuration=None):
    """``--gains`` text -> the ``gains`` argument of :meth:`Scene.run`.

    ``"K"`` sets every gain; ``"K1,K2,..."`` sets the gains in the order of the
    integrator's ``invariant_names``; ``"name=K,..."`` sets the named gains and
    keeps the scene's value for the others (``constraints=K`` sets every ``J_i``);
    ``"auto"`` lets the library choose them from ``dt`` (``gains="auto"``).
    """
    if text is None:
        return None
    if text.strip() == "auto":  # chosen by the library: no integrator to build for the gains' names
        return "auto"
    from .integrator.feedback import parse_gains as _parse

    names = gain_names(scene, variant, configuration)
    try:  # the one gain parser, shared with the API
        return _parse(text, names, defaults=default_gains(scene, names))
    except (TypeError, ValueError) as exc:
        raise UsageError(f"{exc} (scene {scene.name}: gain order {','.join(names) or '(none)'})") from None


def available_schemes(scene):
    """Scheme names ``liefi run SCENE --scheme`` accepts (besides ``scipy:METHOD``)."""
    names = _schemes.names("explicit") + _schemes.names("split")
    return names + [n for n in scene.extra_schemes if n not in names]


def check_scheme(scheme, scene):
    """Raise :class:`UsageError` unless ``scheme`` is available for ``scene``."""
    if scheme is None:
        return
    names = available_schemes(scene)
    if scheme in names:
        return
    if scheme.startswith("scipy:"):
        method = scheme.split(":", 1)[1]
        if method in SCIPY_METHODS:
            return
        raise UsageError(f"scheme: unknown solve_ivp method {method!r}; choose scipy:{'|scipy:'.join(SCIPY_METHODS)}")
    choices = names + ["scipy:METHOD"]
    raise UsageError(f"scheme: {scheme!r} is not available for scene {scene.name}; choose one of {', '.join(choices)}")


def _fmt(x):
    return f"{x:.3e}"


def report(result, file=None):
    """The short human-readable report of ``liefi run``."""
    scene = _scenes.get(result.scene)
    w = (file or sys.stdout).write
    w(f"{result.scene}: {scene.title} (paper {scene.paper}), variant {result.variant}\n")
    w(
        f"  scheme {result.scheme}, dt {result.dt:g}, t in [0, {result.t_final:g}], {result.steps} steps, "
        f"{result.rhs_evaluations} field evaluations\n"
    )
    last = (getattr(result, "method", None) or {}).get("last_step")
    if last is not None:  # a dt that does not divide t_final
        w(f"  the last step shortened to {last:g} to end at t_final\n")
    w(f"  CPU time {result.cpu_seconds:.3f} s\n")
    if result.gains and result.scheme != "dla":
        dropped = {d["name"] for d in getattr(result, "dropped", ())}
        w("  gains " + ", ".join(f"{k}={v:g}" + (f" (kept exactly by {result.scheme}; dropped from V)"
                                                if k in dropped else "")
                                 for k, v in result.gains.items()) + "\n")
    ref = "exact solution" if result.reference == "exact" else "numerical reference (DOP853)"
    w(f"  max |error| against the {ref}:\n")
    width = max([len(k) for k in list(result.max_error) + list(result.max_drift)] + [4])
    for k, v in result.max_error.items():
        w(f"    {k:<{width}}  {_fmt(v)}\n")
    w("  max drift |I(t) - I(0)|:\n")
    for k, v in result.max_drift.items():
        w(f"    {k:<{width}}  {_fmt(v)}\n")


# --------------------------------------------------------------------------------------
# commands
# --------------------------------------------------------------------------------------
def cmd_list(args):
    if getattr(args, "schemes", False):  # the scheme registry: name, kind, order, stability
        print(_schemes.describe())
        return 0
    rows = []
    for name in _scenes.names():
        try:
            s = _scenes.get(name)
        except ImportError as exc:
            rows.append((name, f"(not available: {exc})", "", ""))
            continue
        rows.append((name, s.title, s.paper, ", ".join(s.variants)))
        if args.verbose:
            try:
                costly = s.costly_build()
                if costly:  # the listing does not pay for it: the order is known once the system is built
                    order = order_cfg = f"known once built ({costly}; `liefi run {name} --json` prints the gains)"
                else:
                    order = ",".join(gain_names(s))
                    order_cfg = ",".join(gain_names(s, configuration=True))
            except Exception as exc:  # noqa: BLE001 - listing must not die on one scene
                order = order_cfg = f"? ({exc})"
            extra = f", also {','.join(s.extra_schemes)}" if s.extra_schemes else ""
            rows.append(("", f"dt {s.dt:g}, t_final {s.t_final:g}, scheme {s.scheme}{extra}, "
                             f"reference {s.reference}", "", ""))
            rows.append(("", f"gains {s.gains}; --gains order: {order}"
                             + (f" (with --configuration: {order_cfg})" if order_cfg != order else ""), "", ""))
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows if r[2] or r[3]) if any(r[2] for r in rows) else 0
    w2 = max([len(r[2]) for r in rows] + [0])
    for r in rows:
        if r[2] or r[3]:
            print(f"{r[0]:<{w0}}  {r[1]:<{w1}}  {r[2]:<{w2}}  variants: {r[3]}".rstrip())
        else:
            print(f"{r[0]:<{w0}}  {r[1]}".rstrip())
    return 0


def plot_path(path, scene, variant=None, *, suffix=""):
    """The file ``liefi run --out`` writes, checked before the run.

    A folder gets ``SCENE.png`` (``SCENE-VARIANT.png`` for another variant than the
    first) inside it; a name without a suffix gets ``.png``.  A missing folder (``DIR/``,
    or the folder of ``DIR/FILE.png``) is created, with its parents, as ``liefi bench``
    and ``liefi reproduce`` create theirs.  Raises
    :class:`UsageError` (naming ``out``) when the file cannot be written or its
    suffix is not a format matplotlib writes (:func:`liefi.results.scene_figures.check_format`), and an
    ``ImportError`` with the install hint when matplotlib is missing.
    """
    import os

    from .results import scene_figures as plotting

    plotting.require_matplotlib()
    if path.endswith(("/", os.sep)):
        _make_folder(path)
    if os.path.isdir(path):
        first = next(iter(scene.variants), None)
        name = scene.name + ("" if variant in (None, first) else f"-{variant}") + suffix
        path = os.path.join(path, name + ".png")
    elif not os.path.splitext(path)[1]:
        path += ".png"
    folder = os.path.dirname(os.path.abspath(path))
    _make_folder(folder)
    if os.path.isdir(path):
        raise UsageError(f"out: cannot write {path!r} (a folder of that name is in the way); choose another --out")
    try:
        path = plotting.check_format(path, "out")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    why = probe_writable(path)  # written to and removed: os.access says yes to root even in /proc
    if why is not None:
        raise UsageError(f"out: cannot write {path!r} ({why}); choose another --out")
    return path


def _make_folder(folder):
    """Create ``folder`` (with its parents) if missing, as ``liefi bench`` and ``liefi reproduce`` do."""
    import os

    if os.path.lexists(folder) and not os.path.isdir(folder):
        raise UsageError(f"out: {folder!r} exists and is not a folder; choose another --out")
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"out: cannot create the folder {folder!r} ({exc.strerror or exc}); choose another --out") \
            from None


#: ``liefi run`` refuses more steps than this unless ``--max-steps`` says otherwise
MAX_STEPS = MAX_RUN_STEPS


def check_steps(scene, args):
    """Refuse, before any work, a run of more than ``--max-steps`` steps (default :data:`MAX_STEPS`):
    :func:`liefi.integrator.run.check_step_count`, the check ``liefi bench`` makes too."""
    dt = scene.dt if args.dt is None else args.dt
    T = scene.t_final if args.t_final is None else args.t_final
    try:
        check_step_count(dt, T, args.max_steps,
                         advice="take a larger --dt or a shorter --t-final, or raise --max-steps")
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def run_settings(scene, args):
    """``(scheme, gains_text, dt, rtol, atol, why)`` of ``liefi run``: the best method unless ``--paper``.

    Default: :data:`liefi.integrator.tolerance.DEFAULT_SCHEME` with ``gains auto`` at the
    step chosen for ``--rtol`` (default :data:`liefi.integrator.tolerance.DEFAULT_RTOL`);
    ``--paper``: the scene's paper settings (scheme, gains, dt).  What is given
    explicitly is kept either way.
    """
    from .integrator import tolerance as _tol

    if args.dt is not None and (args.rtol is not None or args.atol is not None):
        raise UsageError("rtol: give --dt or --rtol/--atol, not both (without --dt the step is chosen for the "
                         "tolerance)")
    if args.paper:
        if args.rtol is not None or args.atol is not None:
            raise UsageError("rtol: --paper runs at the paper's step; drop --rtol/--atol or --paper")
        return args.scheme, args.gains, args.dt, None, None, "--paper: the paper's settings of the scene"
    scheme = _tol.DEFAULT_SCHEME if args.scheme is None else args.scheme
    gains = "auto" if args.gains is None else args.gains
    fixed = scheme in _schemes.names("explicit") + _schemes.names("split")
    rtol, atol = args.rtol, args.atol
    if scheme in scene.extra_schemes and (rtol is not None or atol is not None):
        raise UsageError(f"rtol: --scheme {scheme} has no error control and liefi does not choose its step for a "
                         f"tolerance; give --dt (default the scene's {scene.dt:g}) instead of --rtol/--atol, or "
                         "drop --scheme for a step chosen for --rtol")
    if fixed and args.dt is None and rtol is None:
        rtol = _tol.DEFAULT_RTOL
    why = ("liefi's default method (a split scheme imex-rk4/rk6/rk8, gains auto, the order and step for the "
           "tolerance; --paper: the paper's settings)")
    if args.scheme is not None or args.gains is not None or args.dt is not None:
        rest = [] if args.scheme is not None else ["imex-rk4/rk6/rk8" if args.dt is None else scheme]
        if args.gains is None and scheme not in scene.extra_schemes:  # the feedback's gains (also under solve_ivp)
            rest.append("gains auto")
        if args.dt is None:  # what sets the step when --dt is not given
            rest.append("the step for the tolerance" if fixed else "solve_ivp's own steps"
                        if scheme.startswith("scipy:") else f"the scene's step {scene.dt:g}")
        why = "as asked" + (f", liefi's defaults for the rest ({', '.join(rest)})" if rest else "")
    return scheme, gains, args.dt, rtol, atol, why


def cmd_run(args):
    scene = _scenes.get(args.scene)
    variant = scene.variant(args.variant)
    check_scheme(args.scheme, scene)
    scheme, gains_text, dt, rtol, atol, why = run_settings(scene, args)
    configuration = True if args.configuration else None
    path = None
    if args.out:
        path = plot_path(args.out, scene, variant.name)  # before any work
        if scene.figures_need_configuration:
            configuration = True
    gains = parse_gains(gains_text, scene, variant, configuration)
    if rtol is None or dt is not None or scheme.startswith("scipy:") or scheme in scene.extra_schemes:
        check_steps(scene, args)
    else:  # the step for the tolerance, known before the run: refuse a run of hours before it starts
        T = scene.t_final if args.t_final is None else args.t_final
        try:
            step, _ = scene.step_for_tolerance(variant, scheme, T, rtol, args.atol, gains=gains,
                                               configuration=configuration, choose_order=args.scheme is None,
                                               backend=args.backend)
            check_step_count(step, T, args.max_steps, name="rtol",
                             advice=f"the step for rtol {rtol:g}; loosen --rtol, take a shorter --t-final, give a "
                                    "larger --dt, or raise --max-steps")
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    result = scene.run(
        dt=dt,
        t_final=args.t_final,
        scheme=scheme,
        gains=gains,
        variant=variant,
        configuration=configuration,
        backend=args.backend,
        save_every=args.save_every,
        check_stability=args.check_stability,
        adaptive=True if args.adaptive else None,
        rtol=rtol,
        atol=atol,
        choose_order=args.scheme is None and rtol is not None and dt is None,
    )
    if not all(math.isfinite(v) for v in list(result.max_error.values()) + list(result.max_drift.values())):
        raise IntegrationError(
            f"run of {scene.name} produced non-finite errors or drifts; reduce dt or the gains", 0.0, 0, None, []
        )
    out = {"liefi_version": __version__}
    out.update(result.to_dict())
    out["backend"] = result.backend
    out["reference_method"] = scene.reference_method()
    out["configuration"] = bool(configuration) if configuration is not None else scene.needs_configuration()
    out["warnings"] = list(getattr(args, "warnings_seen", []))
    method = dict(result.method) if result.method else {
        "scheme": result.scheme, "dt": result.dt,
        "gains": "none" if result.scheme in scene.extra_schemes else "auto" if gains == "auto" else "fixed",
        "backend": result.backend, "why": f"scheme {result.scheme} as asked"}
    method["why"] = why + "; " + method["why"]
    out["method"] = method
    if path:
        from .results import scene_figures as plotting

        plotting.stack(scene.figures(result), path)
        out["plot"] = path
    if args.json:
        print(_json.dumps(out))
    else:
        report(result)
        if path:
            print(f"  figure written to {path}")
    return 0


def cmd_reproduce(args):
    from . import reproduce

    only = None
    if args.only:
        only = [s.strip() for s in args.only.split(",") if s.strip()]
        for s in only:
            try:
                _scenes.check_name(s)
            except ValueError as exc:
                raise UsageError(f"only: {exc}") from None
    if not (math.isfinite(args.t_final_scale) and args.t_final_scale > 0):
        raise UsageError(f"t-final-scale: must be a positive number, got {args.t_final_scale!r}")
    from .results import scene_figures as plotting

    plotting.require_matplotlib()  # the figures are the point: fail before any work
    try:
        summary = reproduce.reproduce(args.out, only=only, t_final_scale=args.t_final_scale, jobs=args.jobs,
                                      all_scenes=args.all)
    except reproduce.OutputError as exc:
        raise UsageError(str(exc)) from None
    print(reproduce.markdown_table(summary))
    return 1 if summary["failures"] else 0


# --------------------------------------------------------------------------------------
# parser
# --------------------------------------------------------------------------------------
def _positive_float(what):
    def conv(s):
        try:
            v = float(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{s!r} is not a number") from None
        if not (math.isfinite(v) and v > 0):
            raise argparse.ArgumentTypeError(f"{what} must be a positive number, got {s!r}")
        return v

    return conv


def _positive_int(what):
    def conv(s):
        try:
            v = int(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{s!r} is not a whole number") from None
        if v < 1:
            raise argparse.ArgumentTypeError(f"{what} must be a whole number >= 1, got {s!r}")
        return v

    return conv


def build_parser():
    p = _Parser(
        prog="liefi",
        description="Feedback integrators for nonholonomic systems: the paper's experiments (Section 3).",
    )
    p.add_argument("--version", action="version", version=f"liefi {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    pl = sub.add_parser("list", help="the scenes, one line each (name, title, paper section, variants)")
    pl.add_argument("-v", "--verbose", action="store_true", help="also the paper's settings and the --gains order")
    pl.add_argument("--schemes", action="store_true",
                    help="list the schemes instead (name, kind, order, stability), as --scheme and bench --schemes take")

    pr = sub.add_parser(
        "run",
        help="run one scene with liefi's best method (--paper: the paper's settings)",
        description=(
            "Run one scene with liefi's best method unless told otherwise (a split scheme, imex-rk4, imex-rk6 or "
            "imex-rk8, gains auto, the order and step chosen for --rtol, default 1e-6; imex-rk4 with --dt; "
            "--paper: the paper's scheme, gains and step); report the error against the "
            "exact (or numerical reference) solution, the drift of every invariant and the CPU time."
        ),
        epilog=(
            "--gains: one number sets every gain; a comma list K1,K2,... sets them in the order of the "
            "integrator's invariant_names (penalty, then J_1..J_K, then energy, then the scene's own "
            "invariants; 'penalty' only with --configuration on a group with an embedding, e.g. suslov: "
            "J_1,energy, with --configuration penalty,J_1,energy); name=K,... sets named gains and keeps "
            "the paper's value for the rest (constraints=K sets every J_i); 'auto' lets the library choose "
            "them from dt. 'liefi list -v' prints each scene's order. Errors exit with code 2."
        ),
    )
    pr.add_argument("scene", metavar="SCENE", help="scene name (see 'liefi list')")
    pr.add_argument("--dt", type=_positive_float("dt"), default=None,
                    help="step (default: chosen for --rtol; with --paper the paper's); one that does not divide "
                         "--t-final ends with a last step shortened to reach it (the JSON's method says so)")
    pr.add_argument("--rtol", type=_positive_float("rtol"), default=None,
                    help="relative tolerance of the state: the step is chosen for it (default 1e-6; "
                         "with scipy:METHOD its rtol)")
    pr.add_argument("--atol", type=float, default=None,
                    help="absolute tolerance (default 0: relative to each component's size)")
    pr.add_argument("--paper", action="store_true",
                    help="the paper's settings of the scene (scheme, gains, dt) instead of the best method")
    pr.add_argument("--t-final", type=_positive_float("t-final"), default=None, dest="t_final",
                    help="final time (default: the paper's)")
    pr.add_argument("--scheme", default=None,
                    help="|".join(_schemes.names("explicit") + _schemes.names("split")) + "|dla (oscillator)|"
                         "scipy:METHOD (METHOD: " + "|".join(SCIPY_METHODS) + "; default: imex-rk4, imex-rk6 "
                         "or imex-rk8, the order chosen for the tolerance; imex-rk4 with --dt; with --paper the "
                         "paper's)")
    pr.add_argument("--gains", default=None, metavar="K|K1,K2,...|name=K,...|auto",
                    help="feedback gains (default: auto; with --paper the paper's); order: the integrator's invariant_names, see below")
    pr.add_argument("--variant", default=None, help="variant name (default: the scene's first)")
    pr.add_argument("--configuration", action="store_true", help="integrate the group element too")
    pr.add_argument("--backend", default=None, choices=("auto", "numba", "numpy"),
                    help="numpy (reference) or the compiled engine (numba); default auto when numba is installed")
    pr.add_argument("--save-every", type=_positive_int("save-every"), default=None, dest="save_every", metavar="N",
                    help="keep every N-th step (default: at most 20000 saved points)")
    pr.add_argument("--no-check-stability", action="store_false", dest="check_stability",
                    help="skip the stability estimate and monitoring before and during the run")
    pr.add_argument("--max-steps", type=_positive_float("max-steps"), default=None, dest="max_steps", metavar="N",
                    help=f"refuse runs of more than N steps (t_final / dt) before they start (default {MAX_STEPS:.0e})")
    pr.add_argument("--adaptive", action="store_true",
                    help="adapt the gains along the run to the stability limit (liefi.stability)")
    pr.add_argument("--json", action="store_true", help="print one JSON object")
    pr.add_argument("--out", "--plot", default=None, metavar="FILE.png|DIR", dest="out",
                    help="write the scene's figure(s) to FILE.png (into DIR/: DIR/SCENE.png; a missing folder is "
                         "created); checked before the run; integrates the configuration if the figures need it (--plot: the same)")

    pp = sub.add_parser(
        "reproduce",
        help="run every experiment of the paper and write its figures and a summary table",
        description=(
            "Run every scene and variant at the paper's settings (the oscillator with the feedback integrator "
            "and the DLA scheme on [0,200] and the Poincaré sections on [0,400]); write the paper's figures as "
            "PNG and summary.md / summary.json to DIR. Exit code 1 if an experiment failed."
        ),
    )
    pp.add_argument("--out", default="./liefi-out", metavar="DIR", help="output directory (default ./liefi-out)")
    pp.add_argument("--only", default=None, metavar="SCENE[,SCENE]", help="run only these scenes")
    pp.add_argument("--all", action="store_true",
                    help="also the scenes beyond the paper (default: the paper's experiments only)")
    pp.add_argument("--t-final-scale", type=float, default=1.0, dest="t_final_scale", metavar="S",
                    help="(for tests) multiply every horizon by S, e.g. 0.01 for a quick smoke run")
    pp.add_argument("--jobs", type=_positive_int("jobs"), default=None, metavar="N",
                    help="worker processes for independent scenes (default: the number of CPUs)")

    from . import bench as _bench
    from .experiments import stability_cli as _stability

    ps = sub.add_parser(
        "stability",
        help="stability limit of a scene and its measured map in the (dt, gain) plane",
        description=(
            "Estimate the stability limit at the scene's settings (largest eigenvalue of Hess V against the "
            "scheme's real stability bound) and measure the bounded region in the (dt, gain) plane by a sweep."
        ),
    )
    _stability.add_arguments(ps)
    pb = sub.add_parser(
        "bench",
        help="work-precision: error and drift against CPU time for every method on a scene",
        description=(
            "Run every applicable method (feedback integrator, no feedback, constrained equations with "
            "solve_ivp, projection, DLA) over a range of steps or tolerances; write a CSV and PNG diagrams."
        ),
    )
    _bench.add_arguments(pb)
    return p


#: the library's advice in Python spelling -> the flag that does it
_ADVICE = (
    (re.compile(r"\bgains\s*=\s*['\"]auto['\"]"), "--gains auto"),
    (re.compile(r"\badaptive\s*=\s*True\b"), "--adaptive"),
    (re.compile(r"\bcheck_stability\s*=\s*False\b"), "--no-check-stability"),
    (re.compile(r"\bscheme\s*=\s*['\"]([\w:-]+)['\"]"), r"--scheme \1"),
    (re.compile(r"\bsave_every\s*=\s*"), "--save-every "),
    (re.compile(r"\bbackend\s*=\s*['\"](\w+)['\"]"), r"--backend \1"),
)


def as_flags(message):
    """A library message with its advice spelled as ``liefi`` flags (``adaptive=True`` -> ``--adaptive``)."""
    for pattern, flag in _ADVICE:
        message = pattern.sub(flag, message)
    return message


def main(argv=None):
    """Entry point of ``liefi`` / ``python -m liefi``; returns the exit code.

    Warnings (e.g. a step at or past the stability limit) are printed on stderr
    the moment they are raised -- before the run they are about -- once each.
    """
    import warnings

    parser = build_parser()
    seen = []

    def show(message, category, *args, **kwargs):
        msg = " ".join(str(message).split())
        msg = msg[len("liefi: "):] if msg.startswith("liefi: ") else msg
        line = f"{category.__name__}: {as_flags(msg)}"
        if line not in seen:
            seen.append(line)
            print(f"liefi: warning: {line}", file=sys.stderr, flush=True)

    from ._signals import command_returned, terminate_as_interrupt

    try:
        with warnings.catch_warnings(), terminate_as_interrupt():
            warnings.simplefilter("always")
            warnings.showwarning = show
            return command_returned(_main(parser, argv, seen))
    except KeyboardInterrupt as exc:  # landed just outside _main's own handler: the same one line
        return command_returned(_interrupted(exc, _command_of(argv)))


def _command_of(argv):
    """The command word of ``argv`` (``sys.argv[1:]`` for ``None``), or ``None``."""
    words = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("-")]
    return words[0] if words else None


def _interrupted(exc, command=None):
    """Report the interrupt ``exc`` of ``command`` in one line on stderr; its exit code (130 SIGINT, 143 SIGTERM).

    What the line adds: the command's own words (``exc.detail``); for a run stopped in its steps, how far
    it got (``liefi run`` writes nothing then); for ``reproduce`` and ``bench``, that what finished is in
    the output folder; else nothing (``liefi run`` or ``stability`` interrupted before or after its run)."""
    from ._signals import cancel_deadline, describe, exit_code

    cancel_deadline()  # raised and reported: no deadline to end the process
    detail = getattr(exc, "detail", None)
    if not detail and getattr(exc, "t_final", None) is not None and command not in ("reproduce", "bench"):
        detail = f"the run had reached t = {exc.t:.6g} of {exc.t_final:g}; nothing was written"
    if not detail and command in ("reproduce", "bench"):
        detail = "what finished is kept; see the command's output folder"
    print(f"liefi: {describe(exc)}" + (f" ({detail})" if detail else ""), file=sys.stderr)
    return exit_code(exc)


def _main(parser, argv, seen=()):
    try:
        args = parser.parse_args(argv)
        args.warnings_seen = seen
        if args.command is None:
            parser.print_help(sys.stderr)
            return 2
        if args.command == "stability" and args.out:  # the map's file, checked before any work
            args.out = plot_path(args.out, _scenes.get(args.scene), suffix="-stability")
        if args.command == "stability":
            from .experiments.stability_cli import command

            return command(args)
        if args.command == "bench":
            from .bench import run_from_args

            return run_from_args(args)
        return {"list": cmd_list, "run": cmd_run, "reproduce": cmd_reproduce}[args.command](args)
    except UsageError as exc:
        print(f"liefi: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C / SIGINT or SIGTERM: one line, the shell's code (130, 143)
        return _interrupted(exc, _command_of(argv))
    except BrokenPipeError:  # e.g. `liefi list | head`: stop quietly
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except SystemExit as exc:  # --help
        return exc.code if isinstance(exc.code, int) else 0
    except (ValueError, ArithmeticError, RuntimeError, OSError, ImportError) as exc:
        # ValueError: bad scene / variant / dt ...; IntegrationError (an ArithmeticError): a
        # diverging run; RuntimeError: solve_ivp or the reference failed; OSError: an output path;
        # ImportError: an optional extra (matplotlib: liefi[plot]) is missing.
        msg = " ".join(str(exc).split()) or type(exc).__name__
        print(f"liefi: error: {as_flags(msg)}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
