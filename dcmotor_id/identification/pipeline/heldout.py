"""
Stage 11: simulation errors per record, whole and on its held-out part (the JSON ``errors``).

:func:`record_errors` measures the base and the final model on each record: over the whole
record (in-sample), and, when the discovery loop ran, on the held-out end of every record
that the training-part fits never saw, against a constant predictor (the record's mean);
:func:`heldout_warnings` says when a held-out part does not move or the model predicts it
worse than that constant.  :func:`heldout` is the stage.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.identification.error_model.residuals import output_channels, simulation_error_pct
from dcmotor_id.identification.estimators.refined import OutputErrorModel
from dcmotor_id.identification.pipeline.state import Answer, Fit, Inputs

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.discovery import DiscoveryResult
    from dcmotor_id.identification.error_model.residuals import Simulation
    from dcmotor_id.identification.estimators.base import Estimate


#: How the held-out part of every record is chosen (the JSON ``errors.heldout_choice``).
HELDOUT_CHOICE = ('the end of each record carrying the last 30 % of its excitation (the change '
                  'of the outputs beyond their noise; standstill and steady-speed tails add '
                  'none), at most 40 % and at least 15 % of its motion')


def heldout(inputs: Inputs, fit: Fit, answer: Answer) -> Answer:
    """Return the answer with the per-record errors, whole and held out, and their warnings."""
    carried = tuple(found for found in (fit.simulation, answer.simulation) if found is not None)
    errors = record_errors(inputs.records, fit.estimate, answer.final, fit.found,
                           inputs.torque_constant, answer.terms, carried)
    return replace(answer, errors_detail=errors,
                   warnings=answer.warnings + tuple(heldout_warnings(errors)))


def _part_metrics(simulated, measured, outputs, spread=None):
    """
    NRMSE and fit % per channel of one part.

    In percent of this part's own spread, or of ``spread`` (channel -> standard deviation,
    e.g. over the whole record) when given.
    """
    out: dict[str, float | None] = {}
    for channel in ('current', 'speed'):
        value = None
        if channel in outputs and measured[channel].shape[0] > 1:
            if spread is None:
                value = simulation_error_pct(simulated[channel], measured[channel])
            elif spread[channel] > 0:
                residual = np.asarray(simulated[channel]) - measured[channel]
                value = float(np.sqrt(np.mean(residual ** 2))) / spread[channel] * 100.0
                value = value if np.isfinite(value) else None
        out[f'{channel}_nrmse_pct'] = value
        out[f'{channel}_fit_pct'] = None if value is None else 100.0 - value
    return out


def _heldout_item(item, rec, index, found, outputs):
    """Fill a record's held-out figures: segment, errors, constant predictor; moves or not."""
    stop = found.final.stops[index]
    speed = np.asarray(rec.speed, dtype=float)
    held = speed[stop:]
    noise = max(rec.noise_std('speed'), 1e-12)
    moves = held.shape[0] > 5 and float(np.ptp(held)) > 10.0 * noise
    item['heldout_samples'] = int(len(rec) - stop)
    item['heldout_moves'] = bool(moves)
    time_s = np.asarray(rec.time_s, dtype=float)
    item['heldout_segments'] = [{'start_sample': int(stop), 'end_sample': int(len(rec)),
                                 'start_s': float(time_s[stop]), 'end_s': float(time_s[-1])}]
    if not moves:
        return False
    for label, fit in (('before', found.base), ('after', found.final)):
        # Each fit on its own records (a delay found shifts the final one's).
        start = fit.stops[index]
        spread = {c: float(np.std(getattr(fit.records[index], c))) for c in outputs}
        measured = {c: getattr(fit.records[index], c)[start:] for c in outputs}
        item[label]['heldout'] = _part_metrics(
            {c: fit.simulated[index][c][start:] for c in outputs}, measured, outputs, spread)
    item['heldout_constant'] = _part_metrics(
        {c: np.full(measured[c].shape, float(np.mean(getattr(found.final.records[index], c))))
         for c in outputs}, measured, outputs, spread)
    return True


def _worse_than_constant(items):
    """List the records whose held-out error exceeds a constant predictor's (its mean)."""
    worse = []
    for item in items:
        model, constant = item['after']['heldout'], item.get('heldout_constant')
        if not model or not constant:
            continue
        for key in ('current_nrmse_pct', 'speed_nrmse_pct'):
            if model.get(key) is not None and constant.get(key) is not None and \
                    model[key] > constant[key]:
                worse.append(f'{item["source"] or "record"} ({key.split("_")[0]} '
                             f'{model[key]:.3g} % against {constant[key]:.3g} %)')
    return worse


def _pooled(items):
    """Root mean square over records of each figure (records that have it)."""
    keys = {key for item in items for key in item}
    out: dict[str, float | None] = {}
    for key in sorted(keys):
        values = [item[key] for item in items if item.get(key) is not None]
        if not values:
            out[key] = None
        elif key.endswith('fit_pct'):
            out[key] = None
        else:
            out[key] = float(np.sqrt(np.mean(np.square(values))))
    for key in list(out):
        if key.endswith('fit_pct'):
            nrmse = out.get(key.replace('fit_pct', 'nrmse_pct'))
            out[key] = None if nrmse is None else 100.0 - nrmse
    return out


def record_errors(records: Sequence[Record], base: Estimate, final: Estimate,
                  found: DiscoveryResult | None, torque_constant: float | None = None,
                  terms: Sequence = (), carried: Sequence[Simulation] = ()) -> dict[str, Any]:
    """
    Per-record simulation errors, each normalised by its own record (the JSON ``errors``).

    Every figure is the NRMSE in percent of that part's own standard deviation and the
    MATLAB-style fit ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` = ``100 - NRMSE``, per
    channel.  ``whole_record``: the all-data fits simulated over each whole record (in-sample).
    ``heldout``: the training-part fits of the discovery loop on each record's held-out part
    (the end of the record carrying the last share of its excitation,
    :func:`~dcmotor_id.identification.discovery.excited_stop`), in percent of the *whole
    record's* spread (a steady tail's own spread is tiny); None for a record whose held-out
    part does not move.
    ``heldout_constant`` is the same figure for a constant predictor (the record's mean).
    ``carried``: simulations the stages before ran; a fit simulated among them is measured
    on it (:meth:`~dcmotor_id.identification.error_model.residuals.Simulation.is_of`).

    Returns
    -------
    dict
        ``records`` (one ``{"source", "samples", "heldout_samples", "heldout_moves",
        "heldout_segments", "heldout_constant", "before": {"whole_record", "heldout"},
        "after": {...}}`` per record), ``before`` and ``after`` (root mean square over
        records), ``heldout_fraction``, ``heldout_choice``, ``heldout_normalisation``,
        ``worse_than_constant`` (records whose held-out error exceeds the constant's) and
        ``note``.

    """
    mechanical_only = torque_constant is not None
    outputs = output_channels(mechanical_only)
    whole = _whole_records(records, base, final, found, torque_constant, terms, carried)
    items = []
    notes = []
    for index, rec in enumerate(records):
        item: dict[str, Any] = {'source': rec.source, 'samples': len(rec)}
        for label in ('before', 'after'):
            item[label] = {'whole_record': whole[label][index], 'heldout': None}
        if found is not None and not _heldout_item(item, rec, index, found, outputs):
            notes.append(rec.source or f'record {index + 1}')
        items.append(item)
    summary = {label: {part: _pooled([item[label][part] for item in items
                                      if item[label][part] is not None])
                       for part in ('whole_record', 'heldout')} for label in ('before', 'after')}
    note = None
    if notes:
        note = ('held-out part without excitation (its speed holds within its noise: '
                'standstill or a steady speed), not used to judge the fit: '
                + ', '.join(notes))
    worse = _worse_than_constant(items)
    return {'records': items, **summary,
            'heldout_fraction': None if found is None else found.holdout_fraction,
            'heldout_choice': None if found is None else HELDOUT_CHOICE,
            'heldout_normalisation': 'standard deviation of the whole record',
            'worse_than_constant': worse,
            'note': note}


def _whole_records(records, base, final, found, torque_constant, terms, carried):
    """Measure the all-data fits before and after on each whole record (label -> figures)."""
    outputs = output_channels(torque_constant is not None)
    prepared = found.records if found is not None else list(records)
    whole: dict[str, list] = {}
    for label, estimate, record_terms in (('before', base, ()), ('after', final, terms)):
        quasi = bool(estimate.info.get('quasi_static'))
        source = records if label == 'before' else prepared
        model = OutputErrorModel(source, torque_constant, record_terms, quasi)
        ran = next((simulation for simulation in carried if simulation.is_of(
            model, estimate.parameters, estimate.initial_states)), None)
        whole[label] = []
        # One record's simulation at a time, dropped once measured (memory), unless a stage
        # before ran it.
        for index, state in enumerate(estimate.initial_states):
            if ran is not None:
                simulated = ran.outputs[index]
            else:
                with np.errstate(all='ignore'):
                    simulated = model.simulate(estimate.parameters, index,
                                               np.array(state, dtype=float))
            whole[label].append(_part_metrics(
                simulated, {c: getattr(source[index], c) for c in outputs}, outputs))
            del simulated
    return whole


def heldout_warnings(errors: dict[str, Any]) -> list[str]:
    """
    Return the warnings of :func:`record_errors`' result (``errors``), in this order.

    A held-out part without excitation (not used to judge the fit), and records whose held-out
    error exceeds a constant predictor's.
    """
    warnings = []
    if errors.get('note'):
        warnings.append(errors['note'])
    if errors.get('worse_than_constant'):
        warnings.append('on the held-out part the model predicts worse than a constant (the '
                        "record's mean): " + ', '.join(errors['worse_than_constant'])
                        + '; the fit may sit in a wrong basin or miss an effect: compare with '
                        '--initial-state measured and --no-discover')
    return warnings
