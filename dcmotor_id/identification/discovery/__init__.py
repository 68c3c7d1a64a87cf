"""
The effect discovery loop: trace the residual to an effect the model lacks, add it, repeat.

1. Split every record in time: the first part (70 % by default) trains, the rest is held out.
2. Fit the base model on the training part; simulate the whole record (the held-out part continues
   the simulation from the training part) and analyse the held-out residual
   (:mod:`dcmotor_id.identification.error_model.residuals`): Ljung-Box whiteness, predictable
   share,
   correlation with the inputs and with every candidate's regressor.
3. If the residual is not white (by default: on the held-out part or over the whole records,
   :func:`~dcmotor_id.identification.discovery.analysis.stops_before_judging`), try every
   effect of the vocabulary
   (:mod:`dcmotor_id.identification.effects`) not yet in the model.  A cheap linearised screen (the
   residual
   regressed on the sensitivities of the base parameters and of the candidate's terms) picks
   each candidate's inner parameters (Stribeck velocity, cogging period, delay); then *all*
   parameters are refitted on the training part and the candidate is scored by the weighted
   mean squared simulation error on the **held-out** part.
4. The best candidate is added when it lowers the held-out error significantly (the loop's
   rule, :mod:`~dcmotor_id.identification.discovery.judging`: by default the t test of its
   held-out innovations on their effective number; some rules also ask a least gain,
   ``min_gain``, 5 %) and the Bayesian information criterion of the training fit; candidates
   within 2 % of the best one's improvement are a tie, won by the earlier in the vocabulary
   and reported as equivalent.  Repeat until the residual is white or nothing helps.
5. Refit the final structure on all the data (the reported parameters).

``unexplained`` is true when the final held-out residual is still not white *and* an
autoregressive predictor explains at least 5 % of it from its own past (structure of a size
that matters) while no candidate helps: the evidence says how much and where.

:class:`DiscoveryLoop` (:func:`~dcmotor_id.identification.discovery.loop.run_loop`) does all
the fitting; what it found is plain data
(:class:`DiscoveryResult`, its search rounds :class:`Round` of screened and refitted
:class:`Candidate` effects).

One module per seam of the loop; each imports only the modules before it in this list:

- :mod:`~dcmotor_id.identification.discovery.parts`: where a record's held-out part starts;
- :mod:`~dcmotor_id.identification.discovery.structure`: :class:`Structure`, :class:`Fit`,
  :class:`Candidate`, :class:`Round` and the helpers on effect terms and record parts;
- :mod:`~dcmotor_id.identification.discovery.state`: :class:`LoopState`, the loop's frozen
  settings and what its base fit taught it (error weights, the position error's AR(1)
  coefficients, the speed-criterion anchor), which the functions of the modules below take
  as their first argument and never change (a step returns what it found);
- :mod:`~dcmotor_id.identification.discovery.analysis`: the residual analysis of a fit (step 2);
- :mod:`~dcmotor_id.identification.discovery.screening`: the linearised screen (step 3);
- :mod:`~dcmotor_id.identification.discovery.probe`: a costly candidate refit on many
  records first tried on an excerpt of them;
- :mod:`~dcmotor_id.identification.discovery.refitting`: fitting a structure, a candidate's
  refit and its physical problems, the all-data refit (steps 3 and 5);
- :mod:`~dcmotor_id.identification.discovery.arma`: ARMA(1, q) error models of the held-out
  innovations (the rule ``innovation-arma``);
- :mod:`~dcmotor_id.identification.discovery.input_null`: an effect's coefficients against
  their fits to draws of the input current's noise (the rules ``input-noise-null``,
  ``input-noise-null-any-gain`` and the default ``whole-record-white``);
- :mod:`~dcmotor_id.identification.discovery.likelihood`: the training parts' likelihood ratio
  on effective samples, the held-out part a guard (the rule ``all-data-lr``, measured);
- :mod:`~dcmotor_id.identification.discovery.crossval`: blocked cross-validation over the
  whole records, each of its blocks held out in turn (the rules ``blocked-cv`` and
  ``blocked-cv-white``, measured);
- :mod:`~dcmotor_id.identification.discovery.judging`: the held-out gain, its noise, the
  choice and the round's report (step 4);
- :mod:`~dcmotor_id.identification.discovery.result`: :class:`DiscoveryResult`;
- :mod:`~dcmotor_id.identification.discovery.loop`: :class:`DiscoveryLoop`, the search round
  by round, and :func:`discover`; what a round does on its model (screen, refit, analysis)
  is a ``RoundSteps``;
- :mod:`~dcmotor_id.identification.discovery.voltage_speed`: the same rounds on the
  voltage-to-speed model (records without a current), with its own steps.
"""

from dcmotor_id.identification.discovery.analysis import (MATERIAL_FRACTION, MISFIT_FACTOR,
                                                          NEGLIGIBLE_NRMSE_PCT, ONE_STEP_TERMS)
from dcmotor_id.identification.discovery.judging import (GAIN_BLOCKS, GAIN_NOISE_FACTOR, GAIN_T,
                                                         HELDOUT_BLOCKS, heldout_gain_noise,
                                                         never_worse, OWN_PART_SHARE,
                                                         OWN_PART_STRONG, TIE_SHARE)
from dcmotor_id.identification.discovery.loop import discover, DiscoveryLoop
from dcmotor_id.identification.discovery.parts import (EXCITATION_BLOCKS, excited_stop,
                                                       HOLDOUT_FRACTION, moving_extent,
                                                       TRAIN_SHARE_BOUNDS)
from dcmotor_id.identification.discovery.refitting import (CANDIDATE_MAX_NFEV, friction_floors,
                                                           open_loop_outputs, refit_all_data,
                                                           refit_start)
from dcmotor_id.identification.discovery.result import (DiscoveryResult, errors_by_step,
                                                        structure_errors)
from dcmotor_id.identification.discovery.screening import (SCREEN_SHARE, SCREEN_TOP,
                                                           SCREEN_TOP_MISFIT)
from dcmotor_id.identification.discovery.state import LoopState, MAX_EFFECTS, MIN_GAIN
from dcmotor_id.identification.discovery.structure import Candidate, Fit, Round, Structure

__all__ = [
    'CANDIDATE_MAX_NFEV', 'Candidate', 'discover', 'DiscoveryLoop', 'DiscoveryResult',
    'errors_by_step', 'EXCITATION_BLOCKS', 'excited_stop', 'Fit', 'friction_floors',
    'GAIN_BLOCKS', 'GAIN_NOISE_FACTOR', 'GAIN_T', 'HELDOUT_BLOCKS', 'heldout_gain_noise',
    'HOLDOUT_FRACTION', 'LoopState', 'MATERIAL_FRACTION', 'MAX_EFFECTS', 'MIN_GAIN',
    'MISFIT_FACTOR', 'moving_extent', 'NEGLIGIBLE_NRMSE_PCT', 'never_worse', 'ONE_STEP_TERMS',
    'open_loop_outputs', 'OWN_PART_SHARE', 'OWN_PART_STRONG', 'refit_all_data', 'refit_start',
    'Round', 'SCREEN_SHARE', 'SCREEN_TOP', 'SCREEN_TOP_MISFIT', 'Structure', 'structure_errors',
    'TIE_SHARE', 'TRAIN_SHARE_BOUNDS',
]
