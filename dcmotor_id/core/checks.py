"""
One protocol and one registry for the checks of the data and of the answer.

A check says what it looks at and when it runs; the registry holds every check of the package
by name, in the order the checks were registered.  The registry lives on the ground floor so
that every layer can register its own checks where they are written (a layer imports only
downward): the reading layer its read-time checks, ``identification`` those before and after
the fit, ``streaming`` those of a node's incoming batches.  The registry is where a reader
(and ``test/test_checks_registry.py``) finds them all, with their time and home.

When a check runs (:data:`WHEN`):

``read``
    while a file or a message is read: one record, or one batch of a node
    (``core/records.py``, ``formats/quality.py``, ``streaming/input_health.py``);
``before_fit``
    on the prepared records, before the first fit
    (``identification/prepare.py``, ``identification/checks/dropouts.py``,
    ``identification/checks/identifiability.py``);
``after_fit``
    on a fit and its records: the base fit (the start check) or the final fit
    (``identification/checks/``).

What it looks at (:data:`LOOKS_AT`): ``record`` (one record), ``records`` (all the records of
an identification), ``batch`` (a node's incoming message), ``fit`` (an estimate with the
records it was fitted on), ``answer`` (the final fit as the identification reports it).

Checks of one time and subject that share a calling convention are run from here, in their
order of registration (:func:`registered`): the ``before_fit`` checks of one ``record``
(``record -> warning or None``) by the pipeline's first stage, the ``after_fit`` checks of the
``answer`` (``FinalFit -> list of warnings``,
:mod:`dcmotor_id.identification.checks.answer`) by its identifiability stage.  The others are
catalogued here and called by the code that uses their answer (a refusal, repaired records,
a routing, the values not identifiable).

A new check: one function in the home of its time (the modules above), and one line,
``register(Check('name', 'when', 'looks at', function, 'what it says'))`` (for a check of the
answer, in :mod:`dcmotor_id.identification.checks`, where their order is written).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Protocol, runtime_checkable

#: When a check runs, in the order a record meets them.
WHEN = ('read', 'before_fit', 'after_fit')
#: What a check looks at.
LOOKS_AT = ('record', 'records', 'batch', 'fit', 'answer')


@runtime_checkable
class DataCheck(Protocol):
    """
    What every check says of itself: its name, when it runs, what it looks at, what it does.

    ``run`` is the check itself (its arguments and its answer are the function's own: a
    refusal raises :class:`~dcmotor_id.core.errors.DcMotorIdError`, a finding is returned).
    """

    name: str
    when: str
    looks_at: str
    says: str

    @property
    def run(self) -> Callable[..., Any]:
        """Return the function that checks."""


@dataclass(frozen=True)
class Check:
    """
    A registered check (:class:`DataCheck`).

    Parameters
    ----------
    name : str
        Unique name (``excitation``, ``pwm_sampled_current``, ...).
    when : str
        One of :data:`WHEN`.
    looks_at : str
        One of :data:`LOOKS_AT`.
    run : callable
        The check.
    says : str
        What it finds or refuses, in one line.

    """

    name: str
    when: str
    looks_at: str
    run: Callable[..., Any]
    says: str

    def __post_init__(self) -> None:
        """Refuse an unknown time or subject."""
        if self.when not in WHEN:
            raise ValueError(f'check {self.name!r}: when {self.when!r} is not one of '
                             f'{", ".join(WHEN)}')
        if self.looks_at not in LOOKS_AT:
            raise ValueError(f'check {self.name!r}: it looks at {self.looks_at!r}, not one of '
                             f'{", ".join(LOOKS_AT)}')

    @property
    def home(self) -> str:
        """Return the module the check is written in."""
        return str(getattr(self.run, '__module__', ''))


_REGISTRY: dict[str, Check] = {}


def register(check: Check) -> Check:
    """
    Register a check; return it.

    Registering the same function under the same name again (a module imported twice) is a
    no-op; another check under a name already taken is refused.
    """
    known = _REGISTRY.get(check.name)
    if known is not None and known != check:
        raise ValueError(f'a check named {check.name!r} is already registered '
                         f'(in {known.home})')
    _REGISTRY[check.name] = check
    return check


def registered(when: str | None = None, looks_at: str | None = None) -> tuple[Check, ...]:
    """
    Return the registered checks, in their order of registration.

    ``when`` and ``looks_at`` keep those of one time or one subject.  A layer's checks are
    registered when its module is imported.
    """
    return tuple(check for check in _REGISTRY.values()
                 if (when is None or check.when == when)
                 and (looks_at is None or check.looks_at == looks_at))


def registered_check(name: str) -> Check:
    """Return the check of this name; KeyError naming the known ones otherwise."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f'no check named {name!r}; registered: '
                       f'{", ".join(_REGISTRY) or "none"}') from None
