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
Every check is registered where it is written (:mod:`dcmotor_id.core.checks`: one protocol,
one registry of the package's checks with their time and what they look at); a new check is
one function here and one ``register(Check(...))`` line beside it.
"""
