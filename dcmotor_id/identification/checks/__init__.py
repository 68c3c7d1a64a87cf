"""
The checks of the data and of the answer, in the order a record meets them.

0. **Read time** (not here: the reading layer's own check,
   :func:`dcmotor_id.formats.quality.check_channels`): a channel that cannot identify (a current
   sampled inside the PWM cycle, a speed quantised to a few levels, a voltage that never reaches
   the motor) is refused while the file is read.
1. **Before the fit**: :mod:`~dcmotor_id.identification.checks.dropouts` repairs isolated
   dropouts and spikes of the current and speed and names them (the command line and the fleet
   jobs, after reading);
   :func:`~dcmotor_id.identification.checks.identifiability.assess_excitation` says whether
   the motion can identify anything (does the shaft move, does it reverse, is the voltage
   constant, does the current sit at a limit).
2. **After the base fit, before discovery**: :mod:`~dcmotor_id.identification.checks.start`
   checks the fit against model-free evidence and tries a second start when it landed in a
   wrong basin (the JSON's ``start_check``).
3. **After the final fit**: :mod:`~dcmotor_id.identification.checks.identifiability` (bounds,
   correlations, initial states, misfit against the noise, what is not identifiable; a speed
   misfit that the measured current's own noise explains is said so by
   :mod:`~dcmotor_id.identification.checks.input_noise`),
   :mod:`~dcmotor_id.identification.checks.plausibility` (the answer against the scales the
   data imply; refuses what must not be reported) and
   :mod:`~dcmotor_id.identification.checks.units` (a channel off by 1000, named by the
   answer's physics).

:func:`dcmotor_id.identification.identify.identify` runs steps 1 (the excitation) to 3.
Every check is registered (:mod:`dcmotor_id.core.checks`: one protocol, one registry of the
package's checks with their time and what they look at).  The checks of the answer (after the
final fit, each taking a :class:`~dcmotor_id.identification.checks.answer.FinalFit` and
returning its warnings) are registered below, in the order they run and their warnings are
given (:func:`~dcmotor_id.identification.checks.answer.answer_warnings`, which the pipeline
runs): a new one is its module and one ``register`` line here.  The others are registered
beside their function and called by the stage that uses their answer (a refusal, the
excitation, the samples at a current limit, what is not identifiable, the start check).
"""

from dcmotor_id.core.checks import Check, register
from dcmotor_id.identification.checks import identifiability, plausibility, units

register(Check('plausibility', 'after_fit', 'answer', plausibility.plausibility_check,
               'the answer against the scales the data imply (refused, or warnings)'))
register(Check('units', 'after_fit', 'answer', units.units_check,
               "a channel off by 1000, named by the answer's physics"))
register(Check('useful', 'after_fit', 'answer', identifiability.useful_check,
               'nothing useful identified (J, or CPhi in the full mode): refused'))
register(Check('correlated_pairs', 'after_fit', 'answer', identifiability.correlation_check,
               'parameters whose estimates are strongly correlated (a warning)'))
register(Check('initial_states', 'after_fit', 'answer', identifiability.initial_states_check,
               'fitted initial states far from the measured ones (a warning)'))
register(Check('misfit', 'after_fit', 'answer', identifiability.misfit_check,
               'a fit that misses the data by more than their noise (a warning)'))
