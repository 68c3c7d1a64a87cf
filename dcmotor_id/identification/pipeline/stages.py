"""
Stages 5-12 of one run in their order, and a stage attempted: its result or its refusal.

:func:`finish` goes on from :class:`Begun`, a run up to its base's start check (stages 1-4,
:func:`~dcmotor_id.identification.pipeline.run.begin`): discovery, the final start check,
the final fit and its uncertainty, what the data do not determine with the checks of the
answer, the effects' pull, the armature's choice (its part of the standard errors), the
current's noise, the held-out check and the result.  A run left after its start check and
finished later says so on the status line (``Begun.name``).
:func:`attempt` runs a stage and returns the refusal it raised instead of raising it: the
control flow (:mod:`~dcmotor_id.identification.pipeline.run`) compares runs as data.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from dcmotor_id.core.errors import FitError, NotIdentifiableError
from dcmotor_id.core.progress import TimeBudgetExceeded
from dcmotor_id.identification.pipeline.armature import structure_stderr
from dcmotor_id.identification.pipeline.discovery import discovery
from dcmotor_id.identification.pipeline.final_fit import final_fit, uncertainty
from dcmotor_id.identification.pipeline.fit_warnings import fit_warnings
from dcmotor_id.identification.pipeline.heldout import heldout
from dcmotor_id.identification.pipeline.identifiability import identifiability
from dcmotor_id.identification.pipeline.input_noise import input_noise_stderr
from dcmotor_id.identification.pipeline.result import result
from dcmotor_id.identification.pipeline.start_check import check_final_start
from dcmotor_id.identification.pipeline.state import Fit, Inputs
from dcmotor_id.identification.result import IdentificationResult


@dataclass(frozen=True)
class Begun:
    """
    A run up to its base's start check (stages 1-4): what :func:`finish` goes on from.

    ``name``: what the status line calls the run when it is finished later (resumed after
    another run); empty when it goes on at once.
    """

    inputs: Inputs
    fit: Fit
    name: str = ''


def finish(begun: Begun) -> IdentificationResult:
    """Run stages 5-12: discovery to the result (a white run left after its base resumes here)."""
    inputs = begun.inputs
    if begun.name:
        inputs.progress.set_run(begun.name)
    fit = check_final_start(inputs, discovery(inputs, begun.fit))
    answer = uncertainty(inputs, fit, final_fit(inputs, fit))
    answer = fit_warnings(inputs, fit, identifiability(inputs, answer))
    answer = structure_stderr(inputs, fit, answer)
    answer = input_noise_stderr(inputs, fit, answer)
    return result(inputs, fit, heldout(inputs, fit, answer))


def attempt(stage: Callable[..., Any], *arguments: Any, budget_too: bool = False) -> Any:
    """
    Return what ``stage(*arguments)`` returns, or the refusal it raised.

    A refusal for lack of time is raised (the budget is spent for every run), unless
    ``budget_too``.
    """
    try:
        return stage(*arguments)
    except TimeBudgetExceeded as error:
        if budget_too:
            return error
        raise
    except (FitError, NotIdentifiableError) as error:
        if 'time budget' in str(error) and not budget_too:
            raise
        return error
