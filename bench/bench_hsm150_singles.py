"""
Why three HSM150 single records fall outside 15 % of the catalog (issue 19): the current's noise.

The 12 identification records of github malik-robert/HSM150-data (commit 35c3b1b, ``Data/
Identification/idf_{pos,neg}_*.mat``; current column 7, speed column 4, torque constant
0.0458 N m/A) are read as ``bench_real.py`` reads them.  For each record the script measures:

* the noise of the measured current: its standard deviation on the steady parts (4-10 s and
  14-20 s, each detrended), its lag-1 autocorrelation and its spectrum in a low band
  (0.4-2 Hz) against a high one (50-500 Hz): a ratio near 1 is white noise;
* whether the speed follows the current's slow wander: on 14-20 s, both low-passed at 0.5 Hz,
  the spread of the torque the measured current gives against the spread of the torque the
  motion needs (``J dw/dt + b w`` with the catalog J and b), and their correlation;
* the plain output-error fit of ``J dw/dt = K i - b w - F`` (the peer of ``bench_real.py``
  on one direction, here as a linear filter: the speed never reverses after the start) and its
  residual RMS against the speed RMS the current's noise alone gives through the fitted model
  (``sqrt(g^2 s^2 / (1 - a^2))``, ``a = exp(-b dt / J)``, ``g = (1 - a) / b``, ``s`` the
  noise's torque);
* a Monte Carlo of the same fit on the record's own layout: the catalog J and b, the fitted
  friction, a current that holds each step's mean (10 s each), the speed quantised as the
  encoder's (2 pi / 10000 rad per 1 ms), plus noise drawn from the record's own steady-part
  noise (``--runs`` draws): the scatter of J and b and the share outside 15 %; then the same
  with a tenth of the noise (the current averaged over each sample period).

Last, ``dcmotor-id identify`` (the Python API, discovery on) on single records of the
project's own lab simulator of this servo
(:func:`dcmotor_id.simulation.lab_scenarios.servo_opposite_steps`, 0.45 A current noise,
``--seeds`` seeds, one record per direction) and with a tenth of that noise: the spread of J
and b against the truth, and the stated standard errors.  And ``dcmotor-id identify`` on each
real record as a user runs it, by this checkout and (``--before DIR``, e.g. ``git archive
d373b3c dcmotor_id | tar -x -C /tmp/before``) by the code before the current-noise check
(:mod:`dcmotor_id.identification.checks.input_noise`), paired per record, both warmed up: J, b
and the misfit warning.  Set-up as in ``bench_real.py``::

    .venv/bin/python bench/bench_hsm150_singles.py --hsm150 HSM150-data --before /tmp/before \
        --before-commit d373b3c --out bench/hsm150_singles_results.md
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from typing import Any

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from bench_real import HSM150_COMMIT, HSM150_K, HSM150_REFS, Repository  # noqa: E402, I100

DT = 1e-3
SPEED_STEP = 2 * np.pi / 10000 / DT  # one encoder count per sample [rad/s]
J_REF, B_REF = HSM150_REFS['J'], HSM150_REFS['b']
STEADY = ((4.0, 10.0), (14.0, 20.0))


def load(path: str, name: str) -> dict[str, Any]:
    """Read one record, signed so that it moves forward (u: K i [N m], y: speed [rad/s])."""
    from scipy.io import loadmat
    data = np.asarray(loadmat(path)['data'], dtype=float)
    sign = -1.0 if '_neg_' in name else 1.0
    return {'name': name, 't': data[:, 0], 'u': sign * HSM150_K * data[:, 6],
            'y': sign * data[:, 3]}


def simulate(j: float, b: float, friction: float, u: np.ndarray) -> np.ndarray:
    """Speed of ``J dw/dt = u - b w - F`` from rest, the torque held over each sample."""
    from scipy.signal import lfilter
    a = np.exp(-b * DT / j)
    return lfilter([0.0, (1.0 - a) / b], [1.0, -a], u - friction)


def oe_fit(u: np.ndarray, y: np.ndarray) -> dict[str, Any]:
    """Output-error fit of J, b, F (scipy ``least_squares``, scaled by the catalog)."""
    from scipy.optimize import least_squares
    scale = np.array([J_REF, B_REF, 0.03])

    def residual(p: np.ndarray) -> np.ndarray:
        return simulate(*(p * scale), u) - y
    fit = least_squares(residual, np.ones(3), x_scale='jac')
    j, b, friction = fit.x * scale
    return {'J': j, 'b': b, 'F': friction, 'rms': float(np.sqrt(np.mean(fit.fun ** 2)))}


def steady_noise(rec: dict[str, Any]) -> np.ndarray:
    """Return the current's torque on the steady parts, each detrended [N m]."""
    from scipy.signal import detrend
    t = rec['t']
    return np.concatenate([detrend(rec['u'][(t >= lo) & (t < hi)]) for lo, hi in STEADY])


def noise_figures(rec: dict[str, Any]) -> dict[str, float]:
    """Return the current noise's size and whiteness, and whether the speed follows it."""
    from scipy.signal import butter, filtfilt, welch
    noise = steady_noise(rec)
    freq, power = welch(noise, fs=1.0 / DT, nperseg=2048)
    low = power[(freq >= 0.4) & (freq < 2.0)].mean()
    high = power[(freq >= 50.0) & (freq < 500.0)].mean()
    num, den = butter(2, 0.5, fs=1.0 / DT)
    slow_u = filtfilt(num, den, rec['u'])
    slow_y = filtfilt(num, den, rec['y'])
    need = J_REF * np.gradient(slow_y, DT) + B_REF * slow_y
    tail = rec['t'] >= STEADY[1][0]
    a = slow_u[tail] - slow_u[tail].mean()
    c = need[tail] - need[tail].mean()
    mean_current = float(np.mean(np.abs(rec['u'][rec['t'] >= 1.0]))) / HSM150_K
    return {'sigma_a': float(noise.std()) / HSM150_K, 'sigma_torque': float(noise.std()),
            'sigma_pct': 100.0 * float(noise.std()) / HSM150_K / mean_current,
            'acf1': float(np.corrcoef(noise[:-1], noise[1:])[0, 1]), 'white': low / high,
            'slow_current_mnm': 1e3 * float(a.std()), 'slow_need_mnm': 1e3 * float(c.std()),
            'slow_corr': float(np.corrcoef(a, c)[0, 1])}


def propagated_rms(fit: dict[str, Any], sigma_torque: float) -> float:
    """Speed RMS that white torque noise of ``sigma_torque`` gives through the fitted model."""
    a = np.exp(-fit['b'] * DT / fit['J'])
    g = (1.0 - a) / fit['b']
    return float(np.sqrt(g * g * sigma_torque ** 2 / (1.0 - a * a)))


def monte_carlo(rec: dict[str, Any], friction: float, runs: int, shrink: float,
                rng: np.random.Generator) -> dict[str, float]:
    """Fit records of this layout, catalog truth plus the record's own noise times ``shrink``."""
    t, u = rec['t'], rec['u']
    first = t < 10.0
    clean = np.where(first, u[first].mean(), u[~first].mean())
    y = np.round(simulate(J_REF, B_REF, friction, clean) / SPEED_STEP) * SPEED_STEP
    noise = steady_noise(rec) * shrink
    j_err, b_err = [], []
    for _ in range(runs):
        fit = oe_fit(clean + rng.choice(noise, size=u.size), y)
        j_err.append(fit['J'] / J_REF - 1.0)
        b_err.append(fit['b'] / B_REF - 1.0)
    j, b = np.array(j_err), np.array(b_err)
    outside = (np.abs(j) > 0.15) | (np.abs(b) > 0.15)
    return {'J_mean': 100 * j.mean(), 'J_std': 100 * j.std(), 'b_mean': 100 * b.mean(),
            'b_std': 100 * b.std(), 'outside': float(outside.mean())}


def real_rows(repo: Repository, runs: int) -> list[dict[str, Any]]:
    """Every record's noise figures, its fit, and the Monte Carlo at full and a tenth noise."""
    rng = np.random.default_rng(19)
    rows = []
    for name in repo.files('Data/Identification'):
        stem = os.path.basename(name)[:-4]
        rec = load(repo.local(name), stem)
        row = {'name': stem, **noise_figures(rec), 'fit': oe_fit(rec['u'], rec['y'])}
        row['propagated'] = propagated_rms(row['fit'], row['sigma_torque'])
        row['mc'] = monte_carlo(rec, row['fit']['F'], runs, 1.0, rng)
        row['mc_tenth'] = monte_carlo(rec, row['fit']['F'], runs, 0.1, rng)
        print(f'{stem}: done', file=sys.stderr, flush=True)
        rows.append(row)
    return sorted(rows, key=lambda row: row['name'])


def tool_rows(seeds: int) -> list[dict[str, Any]]:
    """``identify`` on single records of the lab simulator, at 0.45 A and 0.045 A noise."""
    from dcmotor_id.identification.identify import identify, prepare_records
    from dcmotor_id.simulation.lab_scenarios import servo_opposite_steps
    rows = []
    for noise in (0.45, 0.045):
        for direction in (0, 1):
            errors: dict[str, list[float]] = {'J': [], 'b': [], 'se_J': [], 'se_b': []}
            start = time.process_time()
            for seed in range(seeds):
                scenario = servo_opposite_steps(seed=seed, current_noise_a=noise)
                record = scenario.records[direction]
                k = scenario.torque_constant
                result = identify(prepare_records([record], torque_constant=k),
                                  torque_constant=k)
                for key in ('J', 'b'):
                    value = result.parameters[key]
                    errors[key].append(100 * (value / getattr(scenario.truth, key) - 1.0))
                    errors['se_' + key].append(100 * result.stderr[key] / value)
            rows.append({'noise': noise, 'record': record.source, 'seeds': seeds,
                         'cpu': time.process_time() - start,
                         **{key: np.array(values) for key, values in errors.items()}})
    return rows


def run_tree(tree: str, args: list[str], out: str) -> dict[str, Any]:
    """Run ``python -m dcmotor_id.cli identify ARGS`` from ``tree``: J, b, stderr, warnings."""
    import json
    import resource
    import subprocess
    env = dict(os.environ, PYTHONPATH=tree)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run([sys.executable, '-m', 'dcmotor_id.cli', 'identify', *args, '--json',
                           out, '--quiet'], cwd=tree, env=env, capture_output=True, text=True,
                          timeout=900)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if done.returncode != 0:
        return {'message': (done.stderr.strip().splitlines() or ['(no message)'])[-1],
                'cpu': cpu}
    with open(out, encoding='utf-8') as stream:
        result = json.load(stream)
    row = {key: result['parameters'][key] for key in ('J', 'b')}
    row.update({'se_' + key: result['stderr'][key] for key in ('J', 'b')})
    row.update(cpu=cpu, warnings=result.get('warnings') or [])
    return row


def warm(tree: str) -> None:
    """Run a tree's warm-up (the set-up's ``python -m dcmotor_id.cli.warmup``)."""
    import subprocess
    subprocess.run([sys.executable, '-m', 'dcmotor_id.cli.warmup'], cwd=tree,
                   env=dict(os.environ, PYTHONPATH=tree), capture_output=True, timeout=900)


def cli_rows(repo: Repository, work: str, trees: dict[str, str]) -> dict[str, dict[str, Any]]:
    """``dcmotor-id identify`` on each real record as a user runs it, by each tree, paired."""
    for tree in trees.values():
        warm(tree)
    rows: dict[str, dict[str, Any]] = {}
    for name in repo.files('Data/Identification'):
        stem = os.path.basename(name)[:-4]
        args = [repo.local(name), '--column', 't=data:1', '--column', 'current=data:7',
                '--column', 'speed=data:4', '--torque-constant', f'{HSM150_K:.6g}']
        rows[stem] = {label: run_tree(tree, args, os.path.join(work, f'{stem}.{label}.json'))
                      for label, tree in trees.items()}
    return rows


def misfit_kind(row: dict[str, Any]) -> str:
    """Return which misfit warning a run gave: the model's, the current noise's, or none."""
    if 'message' in row:
        return 'refused: ' + row['message']
    for text in row['warnings']:
        if text.startswith('the speed misfit') and "current's own noise" in text:
            return "the current's noise ({})".format(text.split('through the model (')[1]
                                                     .split('x the')[0] + 'x')
        if text.startswith('the model misfits far above'):
            return 'the model misfits ({})'.format(text.split('noise: ')[1].split(')')[0])
    return 'none'


def cli_table(cli: dict[str, dict[str, Any]]) -> list[str]:
    """Return the table of the command line's runs, before and after, per record."""
    body = []
    for stem, runs in sorted(cli.items()):
        cells = [stem]
        for label in ('before', 'after'):
            run = runs.get(label)
            if run is None or 'J' not in run:
                cells += ['-', misfit_kind(run) if run else '-', '-']
                continue
            cells += [f'{100 * (run["J"] / J_REF - 1):+.0f} / {100 * (run["b"] / B_REF - 1):+.0f}',
                      misfit_kind(run), f'{run["cpu"]:.1f}']
        body.append(cells)
    return table(['record', 'before: J / b [%]', 'before: misfit warning', 'before: CPU s',
                  'after: J / b [%]', 'after: misfit warning', 'after: CPU s'], body)


def mc_z(row: dict[str, Any]) -> tuple[float, float]:
    """Return how far the record's fit lies from its Monte Carlo, in Monte Carlo spreads."""
    fit, mc = row['fit'], row['mc']
    return ((100 * (fit['J'] / J_REF - 1) - mc['J_mean']) / mc['J_std'],
            (100 * (fit['b'] / B_REF - 1) - mc['b_mean']) / mc['b_std'])


def table(header: list[str], rows: list[list[str]]) -> list[str]:
    """Return a markdown table."""
    return ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)] + [
        '| ' + ' | '.join(row) + ' |' for row in rows]


def real_tables(rows: list[dict[str, Any]], cli: dict[str, dict[str, Any]]) -> list[str]:
    """Return the per-record tables of the real records."""
    noise = [[row['name'], f'{row["sigma_a"]:.3f}', f'{row["sigma_pct"]:.0f}',
              f'{row["acf1"]:+.2f}', f'{row["white"]:.2f}', f'{row["slow_current_mnm"]:.2f}',
              f'{row["slow_need_mnm"]:.2f}', f'{row["slow_corr"]:+.2f}'] for row in rows]
    fits = []
    for row in rows:
        fit, mc, tenth = row['fit'], row['mc'], row['mc_tenth']
        tool = cli.get(row['name'], {}).get('after', {})
        z = (f'{(tool["J"] - J_REF) / tool["se_J"]:+.1f} / '
             f'{(tool["b"] - B_REF) / tool["se_b"]:+.1f}'
             if 'J' in tool else tool.get('message', '-'))
        fits.append([row['name'], f'{100 * (fit["J"] / J_REF - 1):+.0f} / '
                     f'{100 * (fit["b"] / B_REF - 1):+.0f}', f'{fit["rms"]:.2f}',
                     f'{row["propagated"]:.2f}', f'{fit["rms"] / row["propagated"]:.2f}',
                     f'{mc["J_mean"]:+.0f} ± {mc["J_std"]:.0f}',
                     f'{mc["b_mean"]:+.0f} ± {mc["b_std"]:.0f}', f'{100 * mc["outside"]:.0f}',
                     '{:+.1f} / {:+.1f}'.format(*mc_z(row)),
                     f'± {tenth["J_std"]:.1f} / ± {tenth["b_std"]:.1f}', z])
    return (["### The measured current's noise, and whether the speed follows it", ''] + table(
        ['record', 'noise std [A]', '% of the current', 'lag-1 autocorr.',
         'PSD 0.4-2 Hz / 50-500 Hz', 'slow current std [mN m]', 'slow need std [mN m]',
         'correlation'], noise) + ['', '### The fit, its misfit, and the Monte Carlo of the '
                                   "record's layout", ''] + table(
        ['record', 'OE fit J / b [%]', 'residual RMS [rad/s]',
         'RMS from the current noise [rad/s]', 'ratio', 'MC J [%]', 'MC b [%]',
         'MC outside 15 % [%]', 'fit vs MC: z J / b', 'MC a tenth of the noise: std J / b [%]',
         'tool: (value - catalog) / stated stderr, J / b'], fits))


def tool_table(rows: list[dict[str, Any]]) -> list[str]:
    """Return the table of ``identify`` on single records of the lab simulator."""
    body = []
    for row in rows:
        j, b = row['J'], row['b']
        outside = np.mean((np.abs(j) > 15) | (np.abs(b) > 15))
        body.append([f'{row["noise"]:g}', row['record'], str(row['seeds']),
                     f'{j.mean():+.1f} ± {j.std():.1f}', f'{b.mean():+.1f} ± {b.std():.1f}',
                     f'{np.median(row["se_J"]):.1f} / {np.median(row["se_b"]):.1f}',
                     f'{100 * outside:.0f}', f'{row["cpu"]:.0f}'])
    return table(['current noise [A]', 'record', 'seeds', 'J error [%] mean ± std',
                  'b error [%] mean ± std', 'median stated stderr J / b [%]',
                  'outside 15 % [%]', 'CPU s'], body)


def summary(rows: list[dict[str, Any]], tool: list[dict[str, Any]],
            cli: dict[str, dict[str, Any]]) -> list[str]:
    """Return the findings in a few lines."""
    outside = [row['name'] for row in rows
               if max(abs(row['fit']['J'] / J_REF - 1), abs(row['fit']['b'] / B_REF - 1)) > 0.15]
    expected = sum(row['mc']['outside'] for row in rows)
    tenth = sum(row['mc_tenth']['outside'] for row in rows)
    ratio = [row['fit']['rms'] / row['propagated'] for row in rows]
    sigma = [row['sigma_pct'] for row in rows]
    slow = [row['slow_current_mnm'] / row['slow_need_mnm'] for row in rows]
    full = [row for row in tool if row['noise'] == 0.45]
    far = max(rows, key=lambda row: max(np.abs(mc_z(row))))
    bias = np.mean([row['mc']['J_mean'] for row in rows])
    mean_j = 100 * np.mean([row['fit']['J'] / J_REF - 1 for row in rows])
    return [
        f'- The measured current carries white noise of {min(sigma):.0f}-{max(sigma):.0f} % of '
        'the current (the table below: flat spectrum, no autocorrelation); below 0.5 Hz, on '
        f'14-20 s, it swings {min(slow):.1f}-{max(slow):.1f} times as much torque as the '
        'motion needs, uncorrelated: the speed does not follow it, so it is not torque.',
        f'- The output-error residual is {min(ratio):.2f}-{max(ratio):.2f} times the speed RMS '
        "that this noise alone gives through the fitted model: the misfit is the current's "
        'noise integrated by the model.',
        f'- Single records outside 15 % of the catalog (J or b): {len(outside)} of {len(rows)} '
        f'({", ".join(outside) or "none"}); expected from the noise alone (Monte Carlo, '
        f'catalog truth): {expected:.1f} of {len(rows)}; with a tenth of the noise: '
        f'{tenth:.1f}.  The fit lying farthest from its Monte Carlo: {far["name"]} (z J / b '
        '{:+.1f} / {:+.1f}); the Monte Carlo fits J {:+.0f} % off on average (the noise biases '
        'J up), the real fits {:+.0f} %.'.format(*mc_z(far), bias, mean_j),
        '- The tool on its lab simulator of this servo (single records, 0.45 A noise): J '
        + ', '.join(f'{row["J"].mean():+.0f} ± {row["J"].std():.0f} %' for row in full)
        + ', b ' + ', '.join(f'{row["b"].mean():+.0f} ± {row["b"].std():.0f} %' for row in full)
        + ' (forward, back).',
        '- The command line on the 12 real records, misfit warnings: '
        + '; '.join(f'{label}: ' + ', '.join(
            f'{kind} {count}' for kind, count in sorted(
                {kind: [misfit_kind(runs[label]).split(' (')[0] for runs in cli.values()
                        if label in runs].count(kind)
                 for kind in {misfit_kind(runs[label]).split(' (')[0]
                              for runs in cli.values() if label in runs}}.items()))
            for label in ('before', 'after') if any(label in runs for runs in cli.values()))
        + '; J and b are the same (the check changes the warning and the standard errors, '
        'not the fit).']


def head() -> str:
    """Return the short commit of this checkout (and '+' when its bench or package differ)."""
    import subprocess
    root = os.path.dirname(HERE)
    commit = subprocess.run(['git', '-C', root, 'rev-parse', '--short', 'HEAD'],
                            capture_output=True, text=True).stdout.strip() or 'unknown'
    dirty = subprocess.run(['git', '-C', root, 'status', '--porcelain', '--', 'dcmotor_id'],
                           capture_output=True, text=True).stdout.strip()
    return commit + ('+' if dirty else '')


def main() -> None:
    """Run the measurements and print (or write) the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--hsm150', required=True, help='HSM150-data clone (work tree or bare)')
    parser.add_argument('--runs', type=int, default=60, help='Monte Carlo draws per record')
    parser.add_argument('--seeds', type=int, default=20, help='simulator seeds per row')
    parser.add_argument('--before', metavar='DIR',
                        help='a checkout of the code before the change, run beside this one')
    parser.add_argument('--before-commit', default='', help='the commit BEFORE holds')
    parser.add_argument('--out', help='also write the report here')
    args = parser.parse_args()
    load_start = os.getloadavg()
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as work:
        repo = Repository(args.hsm150, HSM150_COMMIT, os.path.join(work, 'HSM150-data'))
        rows = real_rows(repo, args.runs)
        trees = {'before': os.path.abspath(args.before)} if args.before else {}
        cli = cli_rows(repo, work, {**trees, 'after': os.path.dirname(HERE)})
        tool = tool_rows(args.seeds)
    import scipy
    lines = ["# HSM150 single records: the current's noise as a data limit (issue 19)", '',
             f'Command: `.venv/bin/python bench/{os.path.basename(__file__)} --hsm150 '
             f'HSM150-data --runs {args.runs} --seeds {args.seeds}'
             + (' --before BEFORE' if args.before else '') + '`  ',
             f'Code: commit {head()} (after)'
             + (f'; BEFORE: commit {args.before_commit}' if args.before_commit else '') + '  ',
             f'Data: github malik-robert/HSM150-data at {repo.revision()}, '
             '`Data/Identification/idf_{pos,neg}_*.mat` (current column 7, speed column 4)  ',
             f'Machine: {os.cpu_count()} CPUs, Python {platform.python_version()}, numpy '
             f'{np.__version__}, scipy {scipy.__version__}; load average (1, 5, 15 min) at the '
             f'start {", ".join(f"{v:.2f}" for v in load_start)}; '
             f'{time.perf_counter() - start:.0f} s wall clock', '', '## Findings', '',
             *summary(rows, tool, cli), '', '## The real records', '',
             *real_tables(rows, cli), '', '### The command line on each record, before and '
             'after the current-noise check (paired, both trees warmed up)', '',
             *cli_table(cli), '', '## The tool on its lab simulator of this servo', '',
             *tool_table(tool), '']
    report = '\n'.join(lines)
    print(report)
    if args.out:
        with open(args.out, 'w', encoding='utf-8') as stream:
            stream.write(report)


if __name__ == '__main__':
    main()
