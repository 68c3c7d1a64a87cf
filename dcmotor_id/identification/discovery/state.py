"""The loop's settings and working state, which the screening, refitting and judging read."""

from __future__ import annotations

from typing import Sequence, TYPE_CHECKING

from dcmotor_id.core.progress import Progress
from dcmotor_id.identification.criterion import fitted_outputs
from dcmotor_id.identification.discovery.parts import HOLDOUT_FRACTION
from dcmotor_id.identification.discovery.structure import Fit
from dcmotor_id.identification.effects import VOCABULARY
from dcmotor_id.identification.residuals import ALPHA, DEFAULT_LAGS, output_channels

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.effects import Effect


#: Least relative drop of the held-out error for an effect to be added.
MIN_GAIN = 0.05
#: Most effects added.
MAX_EFFECTS = 4


#: The rules a winning candidate may be judged by
#: (:func:`~dcmotor_id.identification.discovery.judging.unearned`): ``heldout-t``, the held-out
#: t test on effective samples, and ``noise-level``, the former own-part and cogging-size
#: rules, kept so that ``bench/bench_discovery.py`` measures both on the same data.
ACCEPTANCE_RULES = ('heldout-t', 'noise-level')
#: The rule of every identification.
DEFAULT_ACCEPTANCE = 'heldout-t'


class LoopState:
    """
    The discovery loop's settings, and what it learns on the way (weights, anchor fit).

    Parameters
    ----------
    records : list of Record
        Prepared records (:func:`dcmotor_id.identification.identify.prepare_records`).
    torque_constant : float, optional
        Mechanical-only mode.
    vocabulary : sequence of Effect classes
        Candidates, in tie-breaking order.
    holdout_fraction : float
        Share of each record held out.
    min_gain : float
        Least relative drop of the held-out error to add an effect.
    max_effects : int
        Most effects added.
    max_lag : int
        Lags of the whiteness test and correlations.
    alpha : float
        Significance level of the tests.
    progress : Progress, optional
        Progress report and time budget; when the budget runs out the loop stops with the
        best structure so far (``out_of_time`` in the result).
    initial_state : str
        ``estimate`` or ``measured``
        (:class:`~dcmotor_id.identification.estimators.refined.RefinedEstimator`).
    quasi_static : bool
        Fit the quasi-static armature (La -> 0; the electrical time constant below the sample
        period) throughout.
    criterion : str
        ``speed`` (default), ``position`` or ``both``: the channels fitted and judged
        (:mod:`dcmotor_id.identification.criterion`); the held-out errors also report the
        speed (and the current) when they are not compared.
    position_error : str
        The position error's model of every fit of the loop, ``adaptive`` (default) or
        ``white`` (:func:`~dcmotor_id.identification.criterion.check_position_error_model`).
    acceptance : str
        The rule a winning candidate must pass, one of :data:`ACCEPTANCE_RULES` (default
        :data:`DEFAULT_ACCEPTANCE`).

    """

    def __init__(self, records: Sequence[Record], torque_constant: float | None = None,
                 vocabulary: Sequence[type[Effect]] = VOCABULARY,
                 holdout_fraction: float = HOLDOUT_FRACTION, min_gain: float = MIN_GAIN,
                 max_effects: int = MAX_EFFECTS, max_lag: int = DEFAULT_LAGS,
                 alpha: float = ALPHA, progress: Progress | None = None,
                 initial_state: str = 'estimate', quasi_static: bool = False,
                 criterion: str = 'speed', position_error: str = 'adaptive',
                 acceptance: str = DEFAULT_ACCEPTANCE) -> None:
        if acceptance not in ACCEPTANCE_RULES:
            raise ValueError(f'unknown acceptance rule {acceptance!r}; one of '
                             f'{", ".join(ACCEPTANCE_RULES)}')
        self.acceptance = acceptance
        self.records = list(records)
        self.torque_constant = torque_constant
        self.mechanical_only = torque_constant is not None
        self.criterion = criterion
        self.position_error = position_error
        self.outputs = fitted_outputs(self.mechanical_only, criterion)
        self.error_channels = output_channels(self.mechanical_only) + tuple(
            channel for channel in self.outputs if channel == 'position')
        self.candidates = [cls for cls in vocabulary if cls.applies(self.mechanical_only)]
        self.holdout_fraction = float(holdout_fraction)
        self.min_gain = float(min_gain)
        self.max_effects = int(max_effects)
        self.max_lag = int(max_lag)
        self.alpha = float(alpha)
        self.weights: dict[str, float] | None = None
        self.progress = progress
        self.initial_state = initial_state
        self.quasi_static = bool(quasi_static) and not self.mechanical_only
        self.anchor: Fit | None = None
        self.position_ar: list[float] | None = None

    @property
    def fitted_weights(self) -> dict[str, float]:
        """Weights of the channels' errors (their noise levels), set by the loop's first fit."""
        if self.weights is None:
            raise ValueError('the error weights are set by the first fit of the loop')
        return self.weights
