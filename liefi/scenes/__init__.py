"""The paper's experiments as scenes (Section 3), loaded on demand.

``liefi.scenes.get("suslov")`` imports only that scene's module.
"""

from __future__ import annotations

import importlib

from .base import PaperRun, RunResult, Scene, Variant

#: scene name -> module (imported lazily, so a run loads only what it needs)
REGISTRY = {
    "suslov": "suslov",
    "knife-edge": "knife_edge",
    "chaplygin": "chaplygin",
    "chaplygin-so2": "chaplygin",
    "vertical-disk": "vertical_disk",
    "roller-racer": "roller_racer",
    "heisenberg": "heisenberg",
    "oscillator": "oscillator",
    "nonreversible-oscillator": "nonreversible",
    "nonreversible-contact-oscillator": "nonreversible",
    "nonreversible-knife-edge": "nonreversible_knife_edge",
    "rigid-body": "rigid_body",
    "heavy-top": "heavy_top",
    "chaplygin-ball": "chaplygin_ball",
    "kepler": "kepler",
    "perturbed-kepler": "kepler",
    "rattleback": "rattleback",
    "rolling-disk": "rolling_disk",
    "bicycle": "bicycle",
}


def names():
    """The scene names, in the paper's order."""
    return list(REGISTRY)


def check_name(name, *, extra=()):
    """Raise a ``ValueError`` naming the closest scene names unless ``name`` is a scene (or in ``extra``).

    The one place an unknown scene name is reported: :func:`get`, ``liefi run``,
    ``liefi bench`` (``extra=("all",)``) and ``liefi reproduce --only`` use it.
    """
    if name in REGISTRY or name in extra:
        return
    import difflib

    close = difflib.get_close_matches(str(name), names() + list(extra), n=3, cutoff=0.6)
    hint = f"did you mean {' or '.join(repr(c) for c in close)}? " if close else ""
    more = "".join(f" or {e!r}" for e in extra)
    raise ValueError(f"scene: unknown scene {name!r}; {hint}choose one of {names()}{more}")


def get(name: str) -> Scene:
    """The scene called ``name`` (see :func:`names`); an unknown name is a ``ValueError`` with the
    closest names (:func:`check_name`)."""
    check_name(name)
    mod = importlib.import_module(f"{__name__}.{REGISTRY[name]}")
    scenes = getattr(mod, "SCENES", None)
    if scenes is not None:
        return scenes[name]
    return mod.SCENE


__all__ = ["Scene", "Variant", "RunResult", "PaperRun", "REGISTRY", "names", "get", "check_name"]
