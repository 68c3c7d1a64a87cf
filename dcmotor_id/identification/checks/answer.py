"""
The checks of the answer, run from the registry: what each looks at, and the one runner.

Every check registered for the time ``after_fit`` that looks at the ``answer``
(:mod:`dcmotor_id.core.checks`) takes a :class:`FinalFit` and returns its warnings (a list
of str, empty when it finds nothing); one that must refuse the answer raises
:class:`~dcmotor_id.core.errors.DcMotorIdError`.  :func:`answer_warnings` runs them all, in
the order they are registered (:mod:`dcmotor_id.identification.checks`, where the order is
written), and the pipeline's identifiability stage calls it once.  A new check of the answer
is one function taking a :class:`FinalFit` and one ``register`` line.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from dcmotor_id.core.checks import registered
from dcmotor_id.identification.error_model.residuals import output_channels


@dataclass(frozen=True)
class FinalFit:
    """
    What the checks of the answer look at: the final fit, its records and its residual.

    ``estimate``: the final estimate (values, standard errors, initial states, ``info``);
    ``records``: the records identified, as the first stage left them; ``fitted_records``: as
    the fitted structure sees them; ``residual_rms``: the RMS of each output channel's
    simulation residual of the final fit; ``said``: the parameters already said not to be
    identifiable, with the reason; ``skip``: parameters whose correlations are not reported
    (at a bound, or given by an upper bound); ``names``: the parameters the answer reports.
    """

    estimate: Any
    records: Sequence[Any]
    fitted_records: Sequence[Any]
    torque_constant: float | None
    initial_state: str
    residual_rms: Mapping[str, float]
    said: Mapping[str, str]
    skip: Sequence[str]
    names: Sequence[str]

    @property
    def mechanical_only(self) -> bool:
        """Whether the torque constant is given (the current is the input)."""
        return self.torque_constant is not None

    @property
    def outputs(self) -> tuple[str, ...]:
        """Return the simulated (output) channels of the fit."""
        return output_channels(self.mechanical_only)


def answer_warnings(fit: FinalFit) -> tuple[str, ...]:
    """Run every registered check of the answer, in their order; return their warnings."""
    return tuple(text for check in registered('after_fit', 'answer') for text in check.run(fit))
