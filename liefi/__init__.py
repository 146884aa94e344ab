"""liefi: feedback integrators for nonholonomic mechanical systems."""
from ._signals import install_for_command as _install_for_command

_install_for_command()  # the `liefi` process only: Ctrl-C while numpy and scipy import is one line and 130
del _install_for_command
from .phase_space import CotangentBundle, LieGroupPhaseSpace, PhaseSpace, TrivialPrincipalBundle
from .systems.system import NonholonomicSystem
from .systems.sympy_input import from_sympy
from .systems.mechanics import from_mechanics
from . import groups, reduction

__version__ = "0.1.0"
from .integrator.feedback import FeedbackIntegrator, Invariant
from .schemes import SCHEMES, ExplicitRungeKutta, IntegrationError, Solution, integrate
from .integrator.linearize import Linearization, Symmetry, linearize, steady_motion

#: the public names of the package (its submodules are documented on their own pages)
__all__ = ["CotangentBundle", "LieGroupPhaseSpace", "PhaseSpace", "TrivialPrincipalBundle", "NonholonomicSystem",
           "from_sympy", "from_mechanics", "groups", "reduction", "FeedbackIntegrator", "Invariant", "SCHEMES",
           "ExplicitRungeKutta", "IntegrationError", "Solution", "integrate", "linearize", "steady_motion",
           "Linearization", "Symmetry", "plot"]


#: the modules users import by their old flat names (``liefi.gains``, ``import liefi.plot``), and where they live
_MOVED = {"system": "systems.system", "sympy_input": "systems.sympy_input", "mechanics": "systems.mechanics",
          "rolling": "systems.rolling", "feedback": "integrator.feedback", "run": "integrator.run",
          "policy": "integrator.policy", "tolerance": "integrator.tolerance", "gains": "integrator.gains",
          "guard": "integrator.guard", "stability": "integrator.stability", "drift": "integrator.drift",
          "dense": "integrator.dense", "dla": "schemes.dla_integrator", "export": "schemes.export",
          "plot": "results.plot", "plotting": "results.scene_figures", "sweep": "results.sweep"}


class _MovedFinder:
    """``import liefi.gains`` finds :mod:`liefi.integrator.gains`: one module under both names."""

    specs = {}

    @staticmethod
    def find_spec(fullname, path=None, target=None):
        pkg, _, name = fullname.rpartition(".")
        if pkg != __name__ or name not in _MOVED:
            return None
        import importlib.util

        return importlib.util.spec_from_loader(fullname, _MovedFinder)

    @staticmethod
    def create_module(spec):
        import importlib

        module = importlib.import_module(f"{__name__}.{_MOVED[spec.name.rpartition('.')[2]]}")
        _MovedFinder.specs[module.__name__] = module.__spec__  # the import system sets __spec__ to the alias's
        return module

    @staticmethod
    def exec_module(module):
        module.__spec__ = _MovedFinder.specs[module.__name__]


def _install_moved():
    import sys

    if not any(f is _MovedFinder for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedFinder)


_install_moved()


def __getattr__(name):
    # the moved modules under their old names (liefi.plot: matplotlib only when drawing), loaded on first use
    if name in _MOVED:
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
