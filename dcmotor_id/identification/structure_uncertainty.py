"""
Standard errors that cover the choice of structure: a noise bootstrap that reruns the loop.

With discovery on, which effects the loop adds depends on the noise of the record at hand: on
a record where an effect is marginal, another noise realisation adds it (or drops it), and the
core parameters move with it by many of their standard errors.  The data-based standard
errors (:mod:`dcmotor_id.identification.estimators.uncertainty`) are those of *one* structure;
on the laboratory scenarios they were 0.2-0.5x the spread over noise realisations with
discovery on (bench/lab_results.md).

:func:`bootstrapped` identifies the records as they are, then ``resamples`` times on records
whose sensor noise was drawn afresh (:func:`resample_noise`), with the whole procedure (the
loop included) rerun each time.  The resamples' estimates are grouped by the structure chosen
(the set of effects); the *between-structure* variance ``sum_g f_g (m_g - m)^2`` (``f_g``
the share of the resamples that chose structure ``g``, ``m_g`` their mean estimate, ``m`` the
mean over all) is the part the choice adds, and ``stderr`` becomes
``sqrt(stderr^2 + between)``.  The variance within a structure is left to the data-based
figure: the resamples are few, and a fresh-noise record is not the record itself.  When every
resample chooses one structure the part is zero and ``stderr`` is unchanged, bit for bit.

On the PWM step records of the laboratory scenarios (2 of 10 seeds add a quadratic drag that
moves b by a quarter) the root mean square of the stated stderr over the spread between seeds
went from 0.45 to 0.90 for b and from 0.52 to 1.18 for Mc (bench/structure_results.md).
Model averaging over the structures the loop already fitted (the candidates of its first
round, weighted by the probability that their held-out gain passes the threshold) was
measured beside it and rejected (b 0.49): on a record where the loop adds nothing, its
candidates lose on the held-out part by tens of percent (the selection is not close on *that*
noise realisation), so the averaging adds nothing, while other noise realisations of the same
experiment add an effect.

Cost: ``resamples`` more identifications; it runs only when asked
(``dcmotor-id identify --structure-bootstrap N``).
"""

from __future__ import annotations

from dataclasses import replace
import time
from typing import Any, Callable, Sequence

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError, InputDataError
from dcmotor_id.core.progress import TimeBudgetExceeded
from dcmotor_id.core.records import Record

#: Width of the running median that separates a channel's signal from its noise [samples].
MEDIAN_WIDTH = 5
#: Channels whose noise is drawn afresh.
CHANNELS = ('voltage', 'current', 'speed', 'position')
#: Seed of the resampling (the result is reproducible).
DEFAULT_SEED = 0
#: Most resamples accepted.
MAX_RESAMPLES = 1000
#: Name of the method in the result.
#: The failure of a resample stopped by the time budget (``--max-time``).
BUDGET_SPENT = 'the time budget (--max-time) ran out'
METHOD = ('noise bootstrap: every channel is its running median (5 samples) plus fresh '
          'Gaussian noise of its measured level (on its quantisation grid when quantised); '
          'the identification, discovery included, is rerun on every resample; the structure '
          'part is the variance between the mean estimates of the structures chosen')
#: Text of the warning (from identify) that the standard errors do not cover the structure.
NOT_COVERED = 'the standard errors do not cover the choice of structure'


def check_resamples(resamples: Any) -> int:
    """Return the number of resamples as an int; an InputDataError when it is not usable."""
    try:
        count = int(resamples)
    except (TypeError, ValueError):
        count = -1
    if count != resamples or not 0 <= count <= MAX_RESAMPLES or count == 1:
        raise InputDataError(
            f'--structure-bootstrap {resamples}: give a whole number of resamples from 2 to '
            f'{MAX_RESAMPLES} (20 is a good start), or 0 to leave the structure choice out')
    return count


def quantisation_step(values: np.ndarray) -> float | None:
    """
    Return the grid step of a quantised channel (every sample a multiple of it), or None.

    The step is the smallest nonzero difference between samples; the channel is quantised when
    every sample lies on the grid through its first sample within 1 % of the step.
    """
    values = np.asarray(values, dtype=float)
    steps = np.abs(np.diff(values))
    steps = steps[steps > 0]
    if not steps.shape[0]:
        return None
    step = float(np.min(steps))
    ratio = (values - values[0]) / step
    if step <= 0 or not np.all(np.abs(ratio - np.round(ratio)) < 0.01):
        return None
    return step


def resample_channel(values: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """
    Return a channel with its noise drawn afresh: its running median plus Gaussian noise.

    The noise level is :func:`~dcmotor_id.signals.filters.noise_std` (second differences,
    robust to steps); a running median keeps steps and monotone stretches exact, so only the
    noise is replaced.  A channel without measurable noise (a commanded voltage, a coarse
    encoder count) comes back unchanged; a quantised one is rounded back onto its grid.
    """
    from scipy.ndimage import median_filter  # lazily: only a bootstrap needs it

    from dcmotor_id.signals.filters import noise_std

    values = np.asarray(values, dtype=float)
    level = noise_std(values)
    if not level > 0 or values.shape[0] < MEDIAN_WIDTH:
        return values.copy()
    smooth = median_filter(values, size=MEDIAN_WIDTH, mode='nearest')
    out = smooth + rng.normal(0.0, level, size=values.shape)
    step = quantisation_step(values)
    if step is not None:
        out = values[0] + np.round((out - values[0]) / step) * step
    return out


def resample_noise(record: Record, rng: np.random.Generator) -> Record:
    """
    Return the record with the noise of every measured channel drawn afresh.

    A speed derived from the position (``speed_derived``) is derived again from the resampled
    position (with the default filter).
    """
    from dcmotor_id.signals.filters import speed_from_position

    channels = {}
    for name in CHANNELS:
        values = getattr(record, name)
        if values is None or (name == 'speed' and record.speed_derived):
            continue
        channels[name] = resample_channel(values, rng)
    if record.speed_derived and 'position' in channels:
        channels['speed'] = speed_from_position(channels['position'], record.sample_period_s)
    return record.replace(**channels)


def structure_key(result: Any) -> tuple[str, ...]:
    """Return the structure a result chose: the sorted names of its effects."""
    return tuple(sorted(effect['name'] for effect in result.effects))


def between_structures(draws: Sequence[tuple[tuple[str, ...], dict[str, float]]],
                       names: Sequence[str]) -> dict[str, float]:
    """
    Return the standard deviation between the structures' mean estimates, per parameter.

    ``sqrt(sum_g f_g (m_g - m)^2)`` over the structures ``g`` of the draws (``f_g`` their
    share, ``m_g`` the mean estimate of the draws that chose ``g``, ``m`` the overall mean);
    zero when every draw chose one structure; NaN for a parameter not finite in every draw.
    """
    groups: dict[tuple[str, ...], list[dict[str, float]]] = {}
    for key, values in draws:
        groups.setdefault(key, []).append(values)
    total = len(draws)
    out = {}
    for name in names:
        means = np.array([np.mean([values[name] for values in group])
                          for group in groups.values()])
        shares = np.array([len(group) / total for group in groups.values()])
        if len(groups) < 2:
            out[name] = 0.0
        elif not np.all(np.isfinite(means)):
            out[name] = float('nan')
        else:
            centre = float(shares @ means)
            out[name] = float(np.sqrt(shares @ (means - centre) ** 2))
    return out


def run_resamples(identify_once: Callable[[list[Record]], Any], records: Sequence[Record],
                  resamples: int, seed: int = DEFAULT_SEED,
                  announce: Callable[[str], None] | None = None,
                  remaining: Callable[[], float] | None = None
                  ) -> tuple[list[tuple[tuple[str, ...], dict[str, float]]], list[str]]:
    """
    Identify ``resamples`` noise resamples of the records; return the draws and the failures.

    Each draw is ``(structure key, parameters)``; a resample the identification refuses is a
    failure (its message), not a draw.  ``announce`` is told which resample runs.  With
    ``remaining`` (seconds left of the time budget), no resample starts once it is spent and
    one that runs out ends the loop (a failure naming the budget).
    """
    rng = np.random.default_rng(seed)
    draws: list[tuple[tuple[str, ...], dict[str, float]]] = []
    failures: list[str] = []
    for index in range(resamples):
        if remaining is not None and remaining() <= 0:
            failures.append(BUDGET_SPENT)
            break
        if announce is not None:
            announce(f'structure bootstrap: resample {index + 1} of {resamples}')
        resampled = [resample_noise(record, rng) for record in records]
        try:
            result = identify_once(resampled)
        except TimeBudgetExceeded:
            failures.append(BUDGET_SPENT)
            break
        except DcMotorIdError as error:
            if remaining is not None and remaining() <= 0:
                failures.append(BUDGET_SPENT)
                break
            failures.append(str(error).split('. ')[0][:200])
            continue
        if remaining is not None and remaining() <= 0:
            failures.append(BUDGET_SPENT)  # its discovery may have been cut short: no draw
            break
        draws.append((structure_key(result), dict(result.parameters)))
    return draws, failures


def summary(result: Any, draws: Sequence[tuple[tuple[str, ...], dict[str, float]]],
            failures: Sequence[str], resamples: int, seed: int,
            part: dict[str, float]) -> dict[str, Any]:
    """Return the JSON account (``structure_uncertainty``) of a bootstrap."""
    counts: dict[tuple[str, ...], int] = {}
    for key, _ in draws:
        counts[key] = counts.get(key, 0) + 1
    done = max(len(draws), 1)
    effects = sorted({name for key in counts for name in key})
    chosen = structure_key(result)
    return {
        'method': METHOD,
        'resamples': int(resamples),
        'completed': len(draws),
        'stopped_by_time_budget': BUDGET_SPENT in failures,
        'failed': len([text for text in failures if text != BUDGET_SPENT]),
        'failures': sorted(set(failures) - {BUDGET_SPENT}),
        'seed': int(seed),
        'chosen_structure': list(chosen),
        'chosen_share': counts.get(chosen, 0) / done,
        'structures': [{'effects': list(key), 'count': count, 'share': count / done}
                       for key, count in sorted(counts.items(), key=lambda item: -item[1])],
        'effect_frequency': {name: sum(count for key, count in counts.items() if name in key)
                             / done for name in effects},
        'stderr_structure': part,
        'stderr_without_structure': dict(result.stderr),
        'included_in_stderr': any(value > 0 for value in part.values()),
    }


def covered(result: Any, part: dict[str, float]) -> Any:
    """Return the result with the structure part added to ``stderr`` (unchanged where 0)."""
    stderr = dict(result.stderr)
    for name, extra in part.items():
        if extra > 0 and np.isfinite(stderr.get(name, np.nan)):
            stderr[name] = float(np.hypot(stderr[name], extra))
    combined = {key: dict(value) for key, value in result.combined.items()}
    friction = combined.get('friction_torque_Nm')
    if friction is not None and np.isfinite(friction.get('stderr', np.nan)):
        friction['stderr'] = stderr['Mc']
    return replace(result, stderr=stderr, combined=combined)


def warnings_for(result: Any, info: dict[str, Any]) -> list[str]:
    """Return the result's warnings as they read once the structure part is known."""
    out = []
    for text in result.warnings:
        if NOT_COVERED in text and info['included_in_stderr']:
            text = text.replace(NOT_COVERED, 'the standard errors include the structure part '
                                'of the noise bootstrap (structure_uncertainty)')
        out.append(text)
    share = info['chosen_share']
    if info['completed'] and share < 0.8:
        others = ', '.join(f'{"+".join(item["effects"]) or "no effect"} '
                           f'{100 * item["share"]:.0f} %' for item in info['structures'])
        out.append(f'the structure is uncertain: on {info["completed"]} noise resamples the '
                   f'loop chose {others}; the standard errors include the spread between '
                   'these structures (structure_uncertainty)')
    if info.get('stopped_by_time_budget'):
        out.append(f'the time budget (--max-time) ran out during the structure bootstrap: '
                   f'{info["completed"]} of {info["resamples"]} resamples were done; its '
                   'figures rest on those (give more --max-time for all of them)')
    elif info['failed'] > info['completed']:
        out.append(f'the structure bootstrap was refused on {info["failed"]} of '
                   f'{info["resamples"]} resamples: its figures rest on few draws')
    return out


def bootstrapped(identify: Callable[..., Any], records: Sequence[Record], resamples: int,
                 seed: int = DEFAULT_SEED, **options: Any) -> Any:
    """
    Identify the records, then cover the structure choice by a noise bootstrap.

    Parameters
    ----------
    identify : callable
        :func:`dcmotor_id.identification.identify.identify` (given, so that this module
        imports nothing above it).
    records : sequence of Record
        The prepared records.
    resamples : int
        Noise resamples (each a full identification with discovery).
    seed : int
        Seed of the resampling.
    options
        The other arguments of ``identify`` (``discover``, ``torque_constant``...).

    Returns
    -------
    IdentificationResult
        With ``structure_uncertainty`` (:func:`summary`), ``stderr`` including the structure
        part, ``elapsed_s`` the whole run time; ``structure_uncertainty`` is
        ``{"skipped": reason}`` when discovery did not run (there is no choice to cover).

    """
    start = time.monotonic()
    resamples = check_resamples(resamples)
    result = identify(records, **options)
    if not resamples:
        return result
    if result.discovery_result is None:
        reason = ('discovery is off: the structure is fixed' if not result.discover else
                  'discovery did not run: ' + str((result.discovery or {}).get('skipped', '')))
        return replace(result, structure_uncertainty={'skipped': reason})
    # The resamples share what is left of the one time budget; the user's progress only
    # names the resample.
    quiet = {key: value for key, value in options.items() if key != 'progress'}
    budget = options.get('max_time_s')
    progress = options.get('progress')
    if progress is not None:
        progress.deadline = None

    def remaining() -> float:
        return float('inf') if budget is None else budget - (time.monotonic() - start)

    def identify_once(sample: list[Record]) -> Any:
        if budget is not None:
            quiet['max_time_s'] = max(remaining(), 1e-9)
        return identify(sample, **quiet)

    draws, failures = run_resamples(identify_once, records, resamples, seed,
                                    None if progress is None else progress.set_stage,
                                    remaining)
    part = between_structures(draws, list(result.parameters)) if draws else {}
    info = summary(result, draws, failures, resamples, seed, part)
    final = covered(result, part)
    return replace(final, structure_uncertainty=info, warnings=warnings_for(result, info),
                   elapsed_s=time.monotonic() - start)
