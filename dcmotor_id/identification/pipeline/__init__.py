"""
The stages of :func:`~dcmotor_id.identification.identify.identify`, one module each.

Every stage is a function from the run's frozen state (:mod:`.state`: :class:`.state.Inputs`,
:class:`.state.Fit`, :class:`.state.Answer`) to a new one; :mod:`.run` calls stages 1-4 and
holds the only branches (the current-limited path, the criterion's fallback to the speed, the
choice of the position error's model), :mod:`.stages` calls stages 5-12 in order.  The base
model on the records (:class:`.state.Models`) and the final fit's simulation travel in the
state, built once::

    Request, RunOn
      -> prepare             1  held samples, coarse channels, excitation   (prepare)
         [current limit]        -> the mechanical-only path + CPhi           (current_limited)
      -> base_fit            2  the estimator on all data                    (base_fit)
      -> armature            3  the quasi-static armature when La is unresolved (armature)
      -> check_base_start    4  further starts, a second start               (start_check,
                                                                             further_starts,
                                                                             second_start)
      -> discovery           5  the effect discovery loop                    (discovery)
      -> check_final_start   6  where discovery led, checked the same way    (start_check)
      -> final_fit           7  refused when it does not reproduce the data  (final_fit)
      -> uncertainty         8  data-based standard errors, La bound          (final_fit)
      -> identifiability     9  what the data do not determine; the checks    (identifiability)
                                of the answer, from the registry
      -> fit_warnings       10  how far the effects moved the base            (fit_warnings)
      -> heldout            11  per-record errors, whole and held out         (heldout)
      -> result             12  the IdentificationResult (the JSON contract)  (result)

On the position, stages 1-4 run with the position error as white noise; when that base (or
the white result) disagrees with the model-free regression the run is made again with the
position error as a drift, and the closer result is kept (:mod:`.position_error`).
:mod:`.fit_outcome` is what every stage measures of a fit: its simulation errors, refused
when non-physical.  Records without a current never enter the stages: :mod:`.voltage_speed`
fits the voltage-to-speed model (kS, kV, kA) instead.
"""
