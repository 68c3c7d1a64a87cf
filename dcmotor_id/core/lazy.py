"""
A package face whose public names are imported from their modules on first use (PEP 562).

The command line imports ``dcmotor_id`` and ``dcmotor_id.streaming.online`` without paying
for the numerics behind every name they list (numba, scipy): a name is imported when it is
first used, then kept in the package like an ordinary attribute.
"""

from __future__ import annotations

import importlib
import sys
from typing import Any, Mapping

__all__ = ['LazyNames', 'bind', 'bound']


class LazyNames:
    """
    The public names of a package and the module of the package that defines each.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    home : dict
        Public name -> module of the package (relative, e.g. ``core.model``).

    """

    def __init__(self, package: str, home: Mapping[str, str]) -> None:
        self.package = package
        self.home = dict(home)
        self.names = sorted(self.home, key=str.lower)

    def load(self, name: str) -> Any:
        """Import ``name`` from its module, keep it in the package, and return it."""
        if name not in self.home:
            raise AttributeError(f'module {self.package!r} has no attribute {name!r}')
        value = getattr(importlib.import_module(f'{self.package}.{self.home[name]}'), name)
        setattr(sys.modules[self.package], name, value)
        return value


#: Name -> ``module:attribute`` of a function a lower floor calls without importing it
#: (filled by the package face ``dcmotor_id``, which sits above every floor).
_BOUND: dict[str, str] = {}


def bind(name: str, target: str) -> None:
    """
    Name a function of a higher floor for the floors below (``module:attribute``, not imported).

    The package face binds, e.g., ``design_controller`` to ``dcmotor_id.design.control``, so
    that :meth:`~dcmotor_id.identification.result.IdentificationResult.design` can hand a
    result to the controller design one floor up without importing upward.
    """
    _BOUND[name] = target


def bound(name: str) -> Any:
    """Return the function bound to ``name`` (imported now); LookupError when none is."""
    if name not in _BOUND:
        raise LookupError(f'nothing is bound to {name!r}: import dcmotor_id (the package face '
                          'binds it)')
    module, attribute = _BOUND[name].split(':')
    return getattr(importlib.import_module(module), attribute)
