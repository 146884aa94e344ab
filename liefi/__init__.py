"""liefi: feedback integrators for nonholonomic mechanical systems."""
from ._signals import install_for_command as _install_for_command

_install_for_command()  # the `liefi` process only: Ctrl-C while numpy and scipy import is one line and 130
del _install_for_command
from .phase_space import CotangentBundle, LieGroupPhaseSpace, PhaseSpace, TrivialPrincipalBundle
from .system import NonholonomicSystem
from .sympy_input import from_sympy
from .mechanics import from_mechanics
from . import groups, reduction

__version__ = "0.1.0"
from .feedback import FeedbackIntegrator, Invariant
from .schemes import SCHEMES, ExplicitRungeKutta, IntegrationError, Solution, integrate

#: the public names of the package (its submodules are documented on their own pages)
__all__ = ["CotangentBundle", "LieGroupPhaseSpace", "PhaseSpace", "TrivialPrincipalBundle", "NonholonomicSystem",
           "from_sympy", "from_mechanics", "groups", "reduction", "FeedbackIntegrator", "Invariant", "SCHEMES",
           "ExplicitRungeKutta", "IntegrationError", "Solution", "integrate", "plot"]


def __getattr__(name):
    # liefi.plot (figures of a run; matplotlib only when drawing) is loaded on first use
    if name == "plot":
        import importlib

        return importlib.import_module(".plot", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
