"""
Issue 19: stated stderr with discovery against the spread over seeds, with the structure part.

Used by ``bench_lab.py --structure-bootstrap N``.  For every seed's discovery run (each with
its noise bootstrap, :mod:`dcmotor_id.identification.structure_uncertainty`) three stated
figures are compared with the standard deviation of the estimates over the seeds (discovery
on, the structure chosen per seed):

- ``without``: the data-based stderr of the structure chosen (what ``stderr`` was before);
- ``bootstrap``: ``stderr`` with the bootstrap's structure part (what it is now);
- ``averaging``: the cheap alternative, a model average over the structures the loop already
  fitted: the base and the candidates of its first round, each weighted by the probability
  that its held-out gain passes the loop's threshold, ``Phi((gain - max(min_gain, noise)) /
  (noise / 2))`` (``noise`` is two standard errors of the gain; a candidate the loop rejected
  for another reason weighs 0), the base by the probability that none passes; the part is the
  weighted spread of the structures' all-data estimates.

Ratios: of the median stated figure (as ``bench_lab.py``'s other columns) and of its root mean
square (the mean stated variance against the variance over the seeds: the fair figure when a
few seeds state large errors and most small ones), and the standard deviation of
``(estimate - mean) / stated`` over the seeds (1 when the stated figures are calibrated).
"""

import math

import numpy as np

from dcmotor_id.identification.discovery import refit_all_data, refit_start, Structure
from dcmotor_id.identification.effects import EFFECTS

#: Candidates of the first round lighter than this are left out of the average (no refit).
LEAST_WEIGHT = 0.01


def selection_probability(report, min_gain):
    """Probability that a candidate's held-out gain passes the loop's threshold (normal)."""
    gain, noise = report.get('heldout_gain_pct'), report.get('heldout_gain_noise_pct')
    if report.get('rejected') or gain is None or noise is None or not math.isfinite(noise) \
            or noise <= 0:
        return 0.0
    threshold = max(min_gain * 100.0, noise)
    return 0.5 * (1.0 + math.erf((gain - threshold) / (noise / 2.0) / math.sqrt(2.0)))


def _candidate_values(found, report):
    """All-data estimate of the base plus one first-round candidate (None when it fails)."""
    names = [effect['name'] for effect in found.effects_json()]
    if names == [report['name']]:
        return found.estimate.parameters
    base = found.base_estimate.parameters
    structure = Structure([(EFFECTS[report['name']], dict(report['inner']))])
    try:
        return refit_all_data(structure, found.source_records, found.torque_constant,
                              dict(base), refit_start(base, found.source_records,
                                                      found.torque_constant),
                              quasi_static=found.quasi_static, criterion=found.criterion
                              )[2].parameters
    except Exception:  # noqa: B902 (a candidate that cannot be refitted weighs nothing)
        return None


def averaging_part(item, names):
    """Per-parameter spread of the model average over the loop's own structures (0: none)."""
    found = item.discovery_result
    if found is None or not found.steps:
        return dict.fromkeys(names, 0.0)
    structures = [(1.0, found.base_estimate.parameters)]
    for report in found.steps[0]['candidates']:
        weight = selection_probability(report, found.min_gain)
        if weight >= LEAST_WEIGHT:
            values = _candidate_values(found, report)
            if values is not None:
                structures[0] = (structures[0][0] * (1.0 - weight), structures[0][1])
                structures.append((weight, values))
    weights = np.array([weight for weight, _ in structures])
    weights = weights / weights.sum()
    out = {}
    for name in names:
        if name not in structures[0][1]:  # not a parameter of the loop's fit (Ra off a limit)
            out[name] = 0.0
            continue
        values = np.array([float(values[name]) for _, values in structures])
        centre = float(weights @ values)
        out[name] = float(np.sqrt(weights @ (values - centre) ** 2))
    return out


def _ratios(values, stated):
    """Median and RMS stated over the seeds' sd, and the sd of the standardised errors."""
    values, stated = np.asarray(values, dtype=float), np.asarray(stated, dtype=float)
    sd = float(np.std(values, ddof=1))
    z = (values - np.mean(values)) / stated
    return (float(np.median(stated)) / sd, float(np.sqrt(np.mean(stated ** 2))) / sd,
            float(np.std(z, ddof=1)))


def structure_rows(covered, truth, result, resamples):
    """Return the markdown lines of the structure-uncertainty comparison of one scenario."""
    names = [name for name in result.parameters if name in truth and
             name not in result.upper_bounds]
    lines = [f'#### Structure choice covered (--structure-bootstrap {resamples})', '',
             '| seed | effects chosen | bootstrap: structures chosen (share) | '
             + ' | '.join(f'{name} stderr without / with structure / averaging' for name in
                          names) + ' |', '|---|---|---|' + '---|' * len(names)]
    stated = {'without': [], 'bootstrap': [], 'averaging': []}
    estimates = []
    for seed, item in covered:
        info = item.structure_uncertainty or {}
        without = info.get('stderr_without_structure', item.stderr)
        part = averaging_part(item, names)
        averaged = {name: math.hypot(without[name], part[name]) for name in names}
        stated['without'].append(without)
        stated['bootstrap'].append(item.stderr)
        stated['averaging'].append(averaged)
        estimates.append(item.parameters)
        shares = ', '.join(f'{"+".join(entry["effects"]) or "none"} '
                           f'{100 * entry["share"]:.0f} %'
                           for entry in info.get('structures', []))
        cells = ' | '.join(
            ' / '.join(f'{100 * figure[name] / abs(item.parameters[name]):.2g} %'
                       for figure in (without, item.stderr, averaged)) for name in names)
        lines.append(f'| {seed} | {", ".join(e["name"] for e in item.effects) or "none"} | '
                     f'{shares} ({info.get("completed", 0)} of {resamples}) | {cells} |')
    lines += ['', '| parameter | sd over seeds, discovery | '
              'median stated / sd: without, bootstrap, averaging | '
              'RMS stated / sd: without, bootstrap, averaging | '
              'sd of (estimate - mean) / stated: without, bootstrap, averaging |',
              '|---|---|---|---|---|']
    for name in names:
        values = [estimate[name] for estimate in estimates]
        figures = [_ratios(values, [entry[name] for entry in stated[kind]])
                   for kind in ('without', 'bootstrap', 'averaging')]
        sd = float(np.std(values, ddof=1))
        lines.append(f'| {name} | {100 * sd / abs(np.mean(values)):.2g} % | '
                     + ' | '.join(', '.join(f'{figure[index]:.2f}' for figure in figures)
                                  for index in range(3)) + ' |')
    return lines + ['']
