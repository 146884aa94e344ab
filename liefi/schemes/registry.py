"""The one table of schemes: adding a scheme is one entry in :data:`ENTRIES`.

Every scheme is an object with

* ``name`` (what ``--scheme`` and ``scheme=`` take), ``kind`` (``"explicit"``,
  ``"split"``, ``"dla"`` or ``"scipy"``), ``order``;
* its stability properties: ``real_stability_bound`` (``beta``; ``inf`` when
  ``stiff_safe``), ``optimal_rate`` (the ``dt lambda_max`` automatic gains aim
  at), ``stiff_safe`` and, for the fixed-step kinds, ``stability_function(z)``;
* ``step(...)``: one step (an explicit tableau: ``step(f, y, dt)``; a split
  scheme: ``bind(fi).step(f, y, dt)``; DLA: ``step(integrator, q_prev, q, h)``;
  ``scipy:METHOD``: one adaptive ``solve_ivp`` call).

Users of the table: ``liefi run --scheme`` (choices and help),
:meth:`liefi.scenes.Scene.run`, :mod:`liefi.integrator.run`, :mod:`liefi.integrator.stability`,
the compiled engine (the explicit tableaux) and ``liefi bench``.
"""

from __future__ import annotations

from .dla import DLA
from .ivp import SCIPY_METHODS
from .rk import TABLEAUX
from .split import SPLIT_SCHEMES

#: Every scheme, in the order the CLI lists them.
ENTRIES = (*TABLEAUX, *SPLIT_SCHEMES.values(), DLA, *SCIPY_METHODS)

#: ``{name: scheme}``.
REGISTRY = {s.name: s for s in ENTRIES}

KINDS = ("explicit", "split", "dla", "scipy")


def names(kind=None):
    """Scheme names, all or of one ``kind`` (``"explicit"``, ``"split"``, ``"dla"``, ``"scipy"``)."""
    if kind is not None and kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    return [s.name for s in ENTRIES if kind is None or s.kind == kind]


def _fold(name):
    s = str(name).strip()
    if s.lower().startswith("scipy:"):
        meth = s.split(":", 1)[1]
        for m in SCIPY_METHODS:
            if m.method.lower() == meth.lower():
                return m.name
        return s
    return s.lower()


def is_scheme_object(x):
    """Whether ``x`` is a scheme object already (what :func:`get` hands back as it is, without ``kind``): not a name."""
    return not isinstance(x, str) and hasattr(x, "name") and (hasattr(x, "kind") or callable(getattr(x, "step", None)))


def get(name, kind=None):
    """The scheme called ``name`` (case-insensitive; a scheme object is returned as is).

    ``kind``: also require this kind.  Raises ``ValueError`` naming the choices.
    """
    if not isinstance(name, str) and hasattr(name, "kind") and hasattr(name, "name"):
        sch = name
    elif not isinstance(name, str) and callable(getattr(name, "step", None)) and hasattr(name, "name"):
        return name  # a user's stepper object (duck-typed)
    else:
        sch = REGISTRY.get(_fold(name))
    if sch is None or (kind is not None and sch.kind not in ((kind,) if isinstance(kind, str) else kind)):
        choices = names() if kind is None else [n for k in ((kind,) if isinstance(kind, str) else kind) for n in names(k)]
        raise ValueError(f"scheme: unknown scheme {name!r}; choose one of {', '.join(choices)}")
    return sch


def takes_scheme(func):
    """Decorator of a public function whose ``scheme`` argument may be a name: the name becomes the registry's
    scheme at the call (:func:`get`, which hands a scheme object, or a split scheme bound to an integrator, back
    as it is).  The body works on the object: a run, which resolves its scheme once in its run loop
    (:mod:`liefi.integrator.run`), hands the object down and no module below looks it up again (an object
    passes without a call to :func:`get`).
    """
    import functools
    import inspect

    pos = list(inspect.signature(func).parameters).index("scheme")

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        if len(args) > pos and not is_scheme_object(args[pos]):
            args = args[:pos] + (get(args[pos]),) + args[pos + 1:]
        elif "scheme" in kwargs and not is_scheme_object(kwargs["scheme"]):
            kwargs["scheme"] = get(kwargs["scheme"])
        return func(*args, **kwargs)

    return wrapper


def describe(kind=None):
    """One line per scheme: name, kind, order, stability (for ``--help`` and ``liefi list``)."""
    lines = []
    for s in ENTRIES:
        if kind is not None and s.kind != kind:
            continue
        stab = "stiff-safe" if s.stiff_safe else f"real stability bound {s.real_stability_bound:.4g}"
        lines.append(f"{s.name:<14} {s.kind:<9} order {s.order:<3} {stab}")
    return "\n".join(lines)
