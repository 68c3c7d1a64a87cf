"""
The loop's frozen settings and what its base fit taught it, which every step of the loop reads.

:class:`LoopState` is a frozen dataclass: no step of the loop changes it.  What the base fit
teaches the loop (the channels' error weights, the position error's AR(1) coefficients, the
pinned initial states, the speed-criterion anchor) is a new state
(:func:`~dcmotor_id.identification.discovery.refitting.taught`, ``dataclasses.replace``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence, TYPE_CHECKING

from dcmotor_id.core.progress import Progress
from dcmotor_id.identification.discovery.parts import HOLDOUT_FRACTION
from dcmotor_id.identification.discovery.structure import Fit
from dcmotor_id.identification.effects import VOCABULARY
from dcmotor_id.identification.error_model.criterion import fitted_outputs
from dcmotor_id.identification.error_model.residuals import ALPHA, DEFAULT_LAGS, output_channels

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.effects import Effect


#: Least relative drop of the held-out error for an effect to be added.
MIN_GAIN = 0.05
#: Most effects added.
MAX_EFFECTS = 4


#: The rules a winning candidate may be judged by
#: (:func:`~dcmotor_id.identification.discovery.judging.unearned`): ``heldout-t``, the held-out
#: t test on effective samples, ``innovation-t``, the same test on the innovations of the
#: residual's AR(1) error model (a drifting position residual is worth a handful of samples,
#: its increments many), and ``noise-level``, the former own-part and cogging-size rules, kept
#: so that ``bench/bench_discovery.py`` measures them all on the same data;
#: ``innovation-t-alone``, that t test on the innovations alone, without asking the gain to be
#: spread over 8 blocks of the held-out part (evidence gathered at a few instants is not);
#: ``innovation-arma``, that test alone on the innovations of an ARMA(1, 2) model of the AR(1)
#: innovations (measured beside the default, not the default); ``input-noise-null`` (the default
#: in rounds 8 and 9), the test of ``innovation-t-alone`` and then the effect's coefficients
#: against their fits to draws of the input current's noise (the mechanical mode's output-error
#: loop; :mod:`~dcmotor_id.identification.discovery.input_null`; elsewhere
#: ``innovation-t-alone``);
#: ``input-noise-null-any-gain`` (the default in round 10), that rule without the least gain
#: (its t test the criterion: ``bench/discovery_results.md``, round 10);
#: ``all-data-lr``, a likelihood-ratio test on effective samples over the training parts, the
#: held-out part a guard against a contradiction
#: (:mod:`~dcmotor_id.identification.discovery.likelihood`; measured, not the default: false
#: effects on real records);
#: ``judged-always``, the tests of ``input-noise-null-any-gain`` with every round judged: the
#: loop does not stop on a white held-out residual
#: (:func:`~dcmotor_id.identification.discovery.analysis.stops_before_judging`; the held-out
#: t test, whose size is measured, is the stop; measured, not the default: the same effects as
#: ``whole-record-white`` at 14 times the CPU of the 60 s record's ``identify``,
#: ``bench/discovery_results.md``, round 11);
#: ``whole-record-white`` (the default since round 11), those tests, the loop stopping on a
#: white held-out residual only when the residual over the whole records is white too
#: (:func:`~dcmotor_id.identification.discovery.analysis.white_on_whole_records`);
#: ``blocked-cv`` and ``blocked-cv-white`` (:data:`CROSS_VALIDATED`, measured in round 12),
#: the winner judged by blocked cross-validation over the whole records
#: (:mod:`~dcmotor_id.identification.discovery.crossval`), the loop judging every round or
#: stopping as ``whole-record-white`` does.
#: The least gain: the screen's share and the rules that ask it
#: (:func:`~dcmotor_id.identification.discovery.judging.least_gain`).
ACCEPTANCE_RULES = ('heldout-t', 'innovation-t', 'noise-level', 'innovation-t-alone',
                    'innovation-arma', 'input-noise-null', 'input-noise-null-any-gain',
                    'all-data-lr', 'judged-always', 'whole-record-white', 'blocked-cv',
                    'blocked-cv-white')
#: Rules judged by blocked cross-validation: candidates ranked by their cross-validated
#: cost, the winner's cross-validated t the test
#: (:func:`~dcmotor_id.identification.discovery.crossval.unearned_cross_validated`).
CROSS_VALIDATED = ('blocked-cv', 'blocked-cv-white')
#: The rule of every identification.
DEFAULT_ACCEPTANCE = 'whole-record-white'


@dataclass(frozen=True, eq=False)
class LoopState:
    """
    The discovery loop's settings, and what its base fit taught it (weights, anchor fit).

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
        Least relative drop of the held-out error to add an effect, under the rules that
        ask one (not those of
        :data:`~dcmotor_id.identification.discovery.judging.GAIN_FREE`, the default among
        them); a candidate is refitted when its screen explains a share of it.
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
        (:mod:`dcmotor_id.identification.error_model.criterion`); the held-out errors also report
        the
        speed (and the current) when they are not compared.
    position_error : str
        The position error's model of every fit of the loop, ``adaptive`` (default) or
        ``white``
        (:func:`~dcmotor_id.identification.error_model.criterion.check_position_error_model`).
    acceptance : str
        The rule a winning candidate must pass, one of :data:`ACCEPTANCE_RULES` (default
        :data:`DEFAULT_ACCEPTANCE`).
    weights : dict, optional
        The channels' error weights (their noise levels); set from the base fit.
    position_ar : list of float, optional
        The position error's AR(1) coefficient per record, from the base fit: it warm-starts
        the candidates' fits.
    anchor : Fit, optional
        The base fitted on the speed when the criterion is not the speed.

    """

    records: Sequence[Record]
    torque_constant: float | None = None
    vocabulary: Sequence[type[Effect]] = VOCABULARY
    holdout_fraction: float = HOLDOUT_FRACTION
    min_gain: float = MIN_GAIN
    max_effects: int = MAX_EFFECTS
    max_lag: int = DEFAULT_LAGS
    alpha: float = ALPHA
    progress: Progress | None = None
    initial_state: str = 'estimate'
    quasi_static: bool = False
    criterion: str = 'speed'
    position_error: str = 'adaptive'
    acceptance: str = DEFAULT_ACCEPTANCE
    weights: Mapping[str, float] | None = None
    position_ar: Sequence[float] | None = None
    anchor: Fit | None = None
    mechanical_only: bool = field(init=False)
    outputs: tuple[str, ...] = field(init=False)
    error_channels: tuple[str, ...] = field(init=False)
    candidates: list[type[Effect]] = field(init=False)

    def __post_init__(self) -> None:
        """Check the acceptance rule; derive the mode, the channels and the candidates."""
        if self.acceptance not in ACCEPTANCE_RULES:
            raise ValueError(f'unknown acceptance rule {self.acceptance!r}; one of '
                             f'{", ".join(ACCEPTANCE_RULES)}')
        mechanical_only = self.torque_constant is not None
        outputs = fitted_outputs(mechanical_only, self.criterion)
        derived: dict[str, Any] = {
            'records': list(self.records), 'mechanical_only': mechanical_only,
            'outputs': outputs,
            'error_channels': output_channels(mechanical_only) + tuple(
                channel for channel in outputs if channel == 'position'),
            'candidates': [cls for cls in self.vocabulary if cls.applies(mechanical_only)],
            'holdout_fraction': float(self.holdout_fraction),
            'min_gain': float(self.min_gain), 'max_effects': int(self.max_effects),
            'max_lag': int(self.max_lag), 'alpha': float(self.alpha),
            'quasi_static': bool(self.quasi_static) and not mechanical_only}
        for name, value in derived.items():
            object.__setattr__(self, name, value)

    @property
    def fitted_weights(self) -> Mapping[str, float]:
        """Weights of the channels' errors (their noise levels), set by the loop's first fit."""
        if self.weights is None:
            raise ValueError('the error weights are set by the first fit of the loop')
        return self.weights
