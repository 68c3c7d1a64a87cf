"""
Real recordings: a scorecard of ``dcmotor-id identify`` and ``validate`` (issue 19).

Public laboratory recordings the project has never been tuned on, each with reference values:
the HSM150 servo (12 open-loop torque steps, 6 per direction), the UBC MECH 467 ball-screw lab
(Part A constant-velocity strokes, Part B a pulse doublet, Part C sines) and EMPS.  The tool is
run as the README tells a user: the command line as a subprocess,
``python -m dcmotor_id.cli identify FILE... --torque-constant K --json OUT`` with the reading
options on the original files (an option that a refusal names, such as ``--sample-period``
for the MECH 467 files' repeated first stamp, is added as a user would, and the refusal is
listed), and ``validate`` on records not fitted.  As the README's set-up does
(``make demo`` installs, then compiles the kernels with ``python -m dcmotor_id.cli.warmup``),
the warm-up runs once before the first fit, timed on its own, so that no row's time is the
first compilation of the kernels.
For every single record, every pair of opposite directions, all records together and disjoint
subsets: the parameters against the references (percent error), the stated standard errors
against the spread between disjoint subsets (z), validation fit %, warnings, exit code and
refusal text, run time (wall and CPU of the process).  Beside it, as the peer, a plain scipy
output-error fit of the same mechanical model
``J dw/dt = K i - b w - Mc sgn(w) - T`` (simulated from the measured current, fitted with
``scipy.optimize.least_squares`` on the speed, or on the position where no speed is logged),
on the same records.  A summary marks each goal of issue 19 met or not met.

Set-up (the data are not part of this repository; their repositories carry no licence to
redistribute them): clone the two public repositories at the named commits, and have the EMPS
files (``DATA_EMPS.mat``, ``DATA_EMPS_PULSES.mat``)::

    git clone https://github.com/malik-robert/HSM150-data && git -C HSM150-data checkout 35c3b1b
    git clone https://github.com/brucecui97/mech467 && git -C mech467 checkout 36dde45

Round 3 (issue 29) adds a WPILib SysId log, a robot's wheel motors, a QUBE-Servo 2 teaching
rig, an FRC drivetrain's SysId log and a lab gearmotor's voltage step from rest, each given to
the default ``identify`` as it comes, with the model-free regression of the tool
(``pipeline/floor.py``; without a current, the voltage-to-speed regression start) on the same
records as the peer::

    git clone https://github.com/calcmogul/SysIdOpt && git -C SysIdOpt checkout f8c2183
    git clone https://github.com/BrOleg5/research-wheel-slippage && \
        git -C research-wheel-slippage checkout 59fc082  # the file is gone from later commits
    git clone https://github.com/JackDelcaro/ACL_LABisca && git -C ACL_LABisca checkout 092cd65

    git clone https://github.com/MiamiBeachBots/base-bot && git -C base-bot checkout 89a98a9
    git clone https://github.com/ryg-delta/SEED_Lab_SP24 && \
        git -C SEED_Lab_SP24 checkout e61c0c4

    .venv/bin/python bench/bench_real.py --sysidopt SysIdOpt --wheels research-wheel-slippage \
        --qube ACL_LABisca --basebot base-bot --seedlab SEED_Lab_SP24 \
        --out bench/real_results_robot_logs.md

Each repository path may be a work tree or a bare clone (``git clone --bare``; its files are
then read at the named commit with ``git show``).  Run from the repository root (one command;
``--quick`` for a subset, ``--only hsm150|mech467|emps``; progress on stderr)::

    .venv/bin/python bench/bench_real.py --hsm150 HSM150-data --mech467 mech467 \
        --emps data/emps --out bench/real_results.md
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import json
import math
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from typing import Any, Optional

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HSM150_COMMIT = '35c3b1b'
MECH467_COMMIT = '36dde45'
HSM150_K = 0.0458
MECH467_K = 0.72
MECH467_GAIN = 0.887
MECH467_PITCH_MM = 20.0
EMPS_GTAU = 35.1507
#: References (J, b, Mc, load torque T; T > 0 opposes positive motion, as ``load_torque``).
HSM150_REFS = {'J': 1.2e-4, 'b': 7.03e-5, 'Mc': 0.024, 'T': 0.009}
MECH467_REFS = {'J': 7e-4, 'Mc': 0.22}
EMPS_REFS = {'J': 95.1089, 'b': 203.5034, 'Mc': 20.3935, 'T': -3.1648}
PARAMETERS = ('J', 'b', 'Mc', 'T')
START = time.perf_counter()


def log(message: str) -> None:
    """Write one progress line on stderr."""
    print(f'[{time.perf_counter() - START:6.0f} s] {message}', file=sys.stderr, flush=True)


@dataclass
class Rec:
    """One record: the file given to the tool and the arrays the peer fits."""

    name: str
    path: str
    direction: str
    t: np.ndarray
    torque: np.ndarray
    y: np.ndarray


@dataclass
class Job:
    """One identification: the records fitted and the records validated on, by group."""

    label: str
    kind: str
    members: list[str]
    heldout: dict[str, list[str]] = field(default_factory=dict)
    family: Optional[str] = None


@dataclass
class DataSet:
    """A data set: records, reading options, torque constant, references, jobs, findings."""

    name: str
    title: str
    records: dict[str, Rec]
    reading: list[str]
    torque_constant: float
    output: str
    refs: dict[str, float]
    jobs: list[Job]
    note: str
    findings: list[dict[str, Any]] = field(default_factory=list)


class Repository:
    """Files of a public repository: a work tree, or a bare clone read at a named commit."""

    def __init__(self, path: str, commit: str, cache: str) -> None:
        # cache: where the files of a bare clone are written (one directory per repository)
        self.path, self.commit, self.cache = path, commit, cache
        if not os.path.isdir(path):
            raise SystemExit(f'{path}: no such directory (see the set-up in bench_real.py)')
        # a directory without .git that git reads as a repository: a bare clone
        self.bare = not os.path.isdir(os.path.join(path, '.git')) and bool(self._git(
            'rev-parse', '--git-dir', check=False).strip())

    def _git(self, *args: str, check: bool = True) -> str:
        where = ['--git-dir', self.path] if not os.path.isdir(
            os.path.join(self.path, '.git')) else ['-C', self.path]
        done = subprocess.run(['git', *where, *args], capture_output=True, text=True)
        if check and done.returncode != 0:
            raise SystemExit(f'{self.path}: git {" ".join(args)} failed: {done.stderr.strip()}')
        return done.stdout

    def revision(self) -> str:
        """Return the commit the files are read at."""
        if self.bare:
            return self.commit
        return self._git('rev-parse', '--short', 'HEAD', check=False).strip() or 'unknown'

    def files(self, folder: str, suffix: str = '.mat') -> list[str]:
        """Return the paths (relative to the repository) of the files of a folder."""
        if self.bare:
            names = self._git('ls-tree', '-r', '--name-only', self.commit, '--', folder).split()
        else:
            base = os.path.join(self.path, folder)
            names = [os.path.join(folder, name) for name in sorted(os.listdir(base))] \
                if os.path.isdir(base) else []
        names = [name for name in names if name.endswith(suffix)]
        if not names:
            raise SystemExit(f'{self.path}: no {suffix} files under {folder}; check out '
                             f'commit {self.commit} (see the set-up in bench_real.py)')
        return names

    def local(self, name: str) -> str:
        """Return a local path of a file (read from the bare clone into the cache)."""
        if not self.bare:
            return os.path.join(self.path, name)
        target = os.path.join(self.cache, name)
        if not os.path.exists(target):
            os.makedirs(os.path.dirname(target), exist_ok=True)
            with open(target, 'wb') as stream:
                subprocess.run(['git', '--git-dir', self.path, 'show',
                                f'{self.commit}:{name}'], stdout=stream, check=True)
        return target


def direction_of(y: np.ndarray, is_position: bool) -> str:
    """Return 'pos', 'neg' or 'both': the directions a record moves in."""
    speed = np.diff(y) if is_position else np.asarray(y)
    moving = np.abs(speed) > 0.1 * np.max(np.abs(speed))
    share = max(int(moving.sum()), 1)
    pos = np.count_nonzero(speed[moving] > 0) > 0.05 * share
    neg = np.count_nonzero(speed[moving] < 0) > 0.05 * share
    return 'both' if pos and neg else ('pos' if pos else 'neg')


def _hsm150_records(repo: Repository) -> dict[str, Rec]:
    """Read the 12 identification records (data columns: t, speed 4, current 7)."""
    from scipy.io import loadmat
    records = {}
    for name in repo.files('Data/Identification'):
        path = repo.local(name)
        data = np.asarray(loadmat(path)['data'], dtype=float)
        stem = os.path.basename(name)[:-4]
        records[stem] = Rec(stem, path, 'neg' if '_neg_' in stem else 'pos', data[:, 0],
                            HSM150_K * data[:, 6], data[:, 3])
    return records


def _hsm150_jobs(names: list[str], quick: bool) -> list[Job]:
    """Every record, the six pos+neg pairs, all 12, the three runs as disjoint subsets."""
    pos = sorted(n for n in names if '_pos_' in n)
    neg = sorted(n for n in names if '_neg_' in n)
    jobs = []
    for name in (pos[:1] + neg[:1] if quick else sorted(names)):
        same = [n for n in (pos if name in pos else neg) if n != name]
        other = neg if name in pos else pos
        jobs.append(Job(name, 'single', [name], {'same dir.': same, 'opposite': other}))
    # idf_pos_0.06_k with idf_neg_0.04_k, idf_pos_0.065_k with idf_neg_0.045_k
    pairs = list(zip(pos, neg))
    for a, b in (pairs[:1] if quick else pairs):
        rest = [n for n in names if n not in (a, b)]
        jobs.append(Job(f'{a[4:]} + {b[4:]}', 'pair', [a, b], {'other 10': rest},
                        family='pairs'))
    jobs.append(Job('all 12', 'all', sorted(names)))
    for run in ('1', '2') if quick else ('1', '2', '3'):
        members = [n for n in sorted(names) if n.endswith('_' + run)]
        rest = [n for n in names if n not in members]
        jobs.append(Job(f'run {run} (4 records)', 'subset', members, {'other 8': rest},
                        family='runs'))
    return jobs


def hsm150_set(path: str, cache: str, quick: bool) -> DataSet:
    """Return the HSM150 servo data set (the original .mat files, read as recorded)."""
    repo = Repository(path, HSM150_COMMIT, os.path.join(cache, 'HSM150-data'))
    records = _hsm150_records(repo)
    reading = ['--column', 't=data:1', '--column', 'current=data:7', '--column',
               'speed=data:4']
    note = (f'github malik-robert/HSM150-data at {repo.revision()}, `Data/Identification/'
            'idf_{pos,neg}_*.mat`: 1 kHz, 20 s, a torque step from rest and a second step '
            'halfway, current (column 7) and speed (column 4). References: catalog J 1.2e-4 '
            'kg m^2, B 7.03e-5 N m s/rad (the authors fit J 1.2153e-4, B 6.95e-5); Coulomb '
            '0.024 N m and offset 0.009 N m from a steady-state regression over all 12 files. '
            'On one-direction fits Mc is the total friction of the direction, compared with '
            'Mc + T = 0.033 N m (positive) or Mc - T = 0.015 N m (negative).')
    findings = [{'data': 'HSM150', 'file': 'every idf_*.mat', 'attempt':
                 'original .mat, ' + ' '.join(reading), 'exit': 0,
                 'message': 'read as recorded'}]
    return DataSet('hsm150', 'HSM150 servo', records, reading, HSM150_K, 'speed', HSM150_REFS,
                   _hsm150_jobs(list(records), quick), note, findings)


MECH467_FIELDS = ('time', 'CH1in', 'CH1out', 'CH1sig')
#: The lab's sample period [s] (2 kHz); every file repeats its first time stamp.
MECH467_PERIOD_S = 0.0005
#: The struct fields as columns of the original .mat file.
MECH467_STRUCT = ['--column', 't=output.time', '--column', 'current=output.CH1sig', '--column',
                  'position=output.CH1out', '--position-counts-per-rev', f'{MECH467_PITCH_MM:g}']
#: What the refusal of the repeated stamp tells a user to add (the time column is then unused).
MECH467_READING = MECH467_STRUCT + ['--sample-period', f'{MECH467_PERIOD_S:g}']


def mech467_columns(mat_path: str) -> np.ndarray:
    """Return the fields of the struct ``output`` of a lab file as columns (as recorded)."""
    from scipy.io import loadmat
    struct = loadmat(mat_path)['output'][0, 0]
    return np.column_stack([np.ravel(struct[name]).astype(float) for name in MECH467_FIELDS])


def _mech467_records(repo: Repository, parts: dict[str, list[str]]) -> dict:
    """Return the original .mat files of each part, with the peer's arrays (SI, motor side)."""
    records = {}
    scale = 2.0 * math.pi / MECH467_PITCH_MM
    for part, stems in parts.items():
        for stem in stems:
            path = repo.local(f'lab1/Group2/Part_{part}/{stem}.mat')
            cols = mech467_columns(path)
            # The tool reads the samples on the grid k T (--sample-period); so does the peer.
            t = MECH467_PERIOD_S * np.arange(cols.shape[0])
            position = scale * cols[:, 2]
            key = f'{part}/{stem}'
            records[key] = Rec(key, path, direction_of(position, True), t,
                               MECH467_K * MECH467_GAIN * cols[:, 3], position)
    return records


def _mech467_stems(repo: Repository, quick: bool) -> dict[str, list[str]]:
    """Return the file stems of each part (numbers in numeric order)."""
    stems = {}
    for part in ('A', 'B', 'C'):
        names = [os.path.basename(n)[:-4] for n in repo.files(f'lab1/Group2/Part_{part}')]
        stems[part] = sorted(names, key=lambda s: (not s.isdigit(), int(s) if s.isdigit()
                                                   else 0, s))
    if quick:
        stems = {'A': [], 'B': stems['B'], 'C': [s for s in stems['C'] if s in ('1', '5', '40')]}
    return stems


def _mech467_jobs(stems: dict[str, list[str]], quick: bool) -> list[Job]:
    """Every record, all of Part C, Part C in two disjoint halves, all parts together."""
    c_names = [f'C/{s}' for s in stems['C']]
    b_names = [f'B/{s}' for s in stems['B']]
    jobs = [Job(name, 'single', [name], {'Part B': b_names}) for name in c_names]
    jobs += [Job(name, 'single', [name], {'Part C': c_names}) for name in b_names]
    jobs += [Job(f'A/{s}', 'single', [f'A/{s}'], {'Part B': b_names}) for s in stems['A']]
    jobs.append(Job('all Part C', 'all', c_names, {'Part B': b_names}))
    if not quick:
        for half, members in (('odd', c_names[0::2]), ('even', c_names[1::2])):
            jobs.append(Job(f'Part C, {half} positions ({len(members)})', 'subset', members,
                            {'Part B': b_names}, family='halves'))
        every = [f'A/{s}' for s in stems['A']] + b_names + c_names
        jobs.append(Job(f'all parts ({len(every)})', 'all', every))
    return jobs


def _mech467_findings(repo: Repository, cache: str, stems: dict[str, list[str]],
                      options: list[str]) -> list[dict[str, Any]]:
    """
    Read the first file of each part as a user would; return the attempts.

    The .mat with its struct fields, then with what the refusal says (``--sample-period``);
    the second is what every row uses.
    """
    findings = []
    for part, names in stems.items():
        if not names:
            continue
        name = f'lab1/Group2/Part_{part}/{names[0]}.mat'
        for label, reading in (('original .mat, struct fields', MECH467_STRUCT),
                               ('original .mat, struct fields, as the refusal tells',
                                MECH467_READING)):
            run = run_cli(['identify', repo.local(name), *reading, *options, '--json',
                           os.path.join(cache, 'finding.json')])
            findings.append({'data': 'MECH 467', 'file': f'Part_{part}/{names[0]}.mat',
                             'attempt': f'{label}: ' + ' '.join(reading),
                             'exit': run['rc'], 'message': run['message'] or 'read'})
    return findings


def mech467_set(path: str, cache: str, quick: bool) -> DataSet:
    """Return the UBC MECH 467 ball-screw lab, Group 2 (the original .mat files)."""
    repo = Repository(path, MECH467_COMMIT, os.path.join(cache, 'mech467'))
    stems = _mech467_stems(repo, quick)
    records = _mech467_records(repo, stems)
    k = MECH467_K * MECH467_GAIN
    options = ['--torque-constant', f'{k:.6g}']
    note = (f'github brucecui97/mech467 at {repo.revision()}, `lab1/Group2/Part_{{A,B,C}}/'
            '*.mat`: 2 kHz, struct `output` with `time`, `CH1sig` (the commanded current in V, '
            f'amplifier {MECH467_GAIN} A/V), `CH1out` (table position, mm), `CH1in` (the '
            'reference).  Every file repeats its first time stamp: the tool refuses it and '
            'names `--sample-period`, which every row gives '
            f'(`--sample-period {MECH467_PERIOD_S:g}`, the time column is then not used).  '
            'Torque constant 0.72 N m/A times the amplifier gain: '
            f'`--torque-constant {k:.6g}` with the command in V as the current (no current-gain '
            'option); the screw pitch 20 mm/rev as `--position-counts-per-rev 20` (mm counted '
            '20 per revolution; `--position-unit` has no mm, and `m` is kept as metres), so J '
            'is at the motor shaft.  References: lab manual J about 7e-4 kg m^2, the Coulomb '
            'friction of the group about 0.22 N m.  Every record moves both ways (no direction '
            'pairs); Part B is the validation record of the Part C fits.')
    findings = _mech467_findings(repo, cache, stems, options)
    return DataSet('mech467', 'UBC MECH 467 ball screw', records, MECH467_READING, k,
                   'position', MECH467_REFS, _mech467_jobs(stems, quick), note, findings)


EMPS_FILES = ('DATA_EMPS', 'DATA_EMPS_PULSES')


def emps_set(path: str, quick: bool) -> DataSet:
    """EMPS: the estimation and the pulses record (the original .mat files)."""
    from scipy.io import loadmat
    records = {}
    for stem in EMPS_FILES:
        file = os.path.join(path, stem + '.mat')
        if not os.path.isfile(file):
            raise SystemExit(f'{file}: missing (EMPS data: python bench/fetch_emps.py DIR '
                             'downloads them)')
        data = loadmat(file)
        gtau = float(np.ravel(data['gtau'])[0])
        records[stem] = Rec(stem, file, 'both', np.ravel(data['t']).astype(float),
                            gtau * np.ravel(data['vir']), np.ravel(data['qm']).astype(float))
    reading = ['--column', 'current=vir', '--column', 'position=qm', '--position-unit', 'm']
    jobs = [Job(stem, 'single', [stem], {'other record': [s for s in EMPS_FILES if s != stem]},
                family='records') for stem in EMPS_FILES[:1 if quick else 2]]
    if not quick:
        jobs.append(Job('both records', 'all', list(EMPS_FILES)))
    note = ('EMPS (Janot, Gautier, Brunot 2019; the public records, bench/fetch_emps.py): a '
            'current-controlled ball-screw drive in closed position loop, 1 kHz, force '
            f'`gtau vir` (gtau {EMPS_GTAU} N/V as the torque constant), carriage position `qm` '
            'in m (M, Fv, Fc, offset in the roles of J, b, Mc, T).  References: the published '
            'IDIM-LS M 95.1089 kg, Fv 203.5034 N s/m, Fc 20.3935 N, offset -3.1648 N.  Both '
            'records move both ways (no direction pairs); the two records are the disjoint '
            'subsets.')
    findings = [{'data': 'EMPS', 'file': 'DATA_EMPS*.mat', 'attempt': 'original .mat, '
                 + ' '.join(reading), 'exit': 0, 'message': 'read as recorded'}]
    return DataSet('emps', 'EMPS', records, reading, EMPS_GTAU, 'position', EMPS_REFS, jobs,
                   note, findings)


PATH_PATTERN = re.compile(r'(?:/[^\s:\'"/]+)+/([^\s:\'"/]+\.(?:mat|csv|json))')


def shorten(text: str) -> str:
    """Replace absolute file paths in a message by the file names."""
    return PATH_PATTERN.sub(r'\1', text)


def cli_module() -> str:
    """Return the module behind ``python -m`` for the command line of this checkout."""
    package = os.path.join(ROOT, 'dcmotor_id', 'cli')
    if os.path.isdir(package) and not os.path.exists(os.path.join(package, '__main__.py')):
        return 'dcmotor_id.cli.main'
    return 'dcmotor_id.cli'


def run_cli(args: list[str], timeout_s: float = 900.0,
            module: Optional[str] = None) -> dict[str, Any]:
    """
    Run ``python -m dcmotor_id.cli ARGS`` from this checkout; return exit code and times.

    ``message`` is the error line of a refusal (exit code other than 0), else ''; ``wall``
    and ``cpu`` are the process's wall-clock and CPU seconds (user + system).  ``module``
    runs another module of the package instead (the set-up's warm-up).
    """
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [ROOT] + ([os.environ['PYTHONPATH']] if os.environ.get('PYTHONPATH') else [])))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    try:
        done = subprocess.run([sys.executable, '-m', module or cli_module(), *args], cwd=ROOT,
                              env=env,
                              capture_output=True, text=True, timeout=timeout_s)
        rc, stderr = done.returncode, done.stderr
    except subprocess.TimeoutExpired:
        rc, stderr = -1, f'killed after {timeout_s:g} s'
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    lines = [line for line in stderr.splitlines() if line.strip()]
    errors = [line for line in lines if 'error' in line.lower()]
    message = '' if rc == 0 else shorten((errors or lines or ['(no message)'])[-1])
    return {'rc': rc, 'message': message, 'wall': wall, 'cpu': cpu}


def warm_up() -> dict[str, Any]:
    """Run the set-up's warm-up (``make demo`` runs it at install); return its times."""
    run = run_cli([], module='dcmotor_id.cli.warmup')
    log(f'set-up warm-up: exit {run["rc"]} in {run["wall"]:.1f} s (CPU {run["cpu"]:.1f} s)')
    return run


def validate_fits(ds: DataSet, model_json: str, names: list[str], work: str) -> dict:
    """Run ``validate`` on records not fitted; return {record name: fit %} or an error."""
    out = os.path.join(work, 'validate.json')
    files = [ds.records[name].path for name in names]
    run = run_cli(['validate', model_json, *files, *ds.reading, '--json', out])
    if run['rc'] != 0:
        return {'error': run['message'] or f'exit {run["rc"]}'}
    with open(out) as stream:
        records = json.load(stream)['records']
    if len(records) != len(names):
        return {'error': f'{len(records)} results for {len(names)} records'}
    fits = {}
    for name, record in zip(names, records):
        value = record['fit_pct'].get(ds.output)
        fits[name] = float('nan') if value is None else float(value)
    return fits


def validate_groups(ds: DataSet, model_json: str, groups: dict[str, list[str]],
                    work: str) -> dict[str, dict]:
    """Validate on the records of every group in one run; return the fits by group."""
    names = list(dict.fromkeys(name for members in groups.values() for name in members))
    if not names:
        return {}
    fits = validate_fits(ds, model_json, names, work)
    if 'error' in fits:
        return dict.fromkeys(groups, fits)
    return {group: {name: fits[name] for name in members} for group, members in groups.items()}


def simulate(theta: np.ndarray, rec: Rec, position: bool) -> np.ndarray:
    """
    Simulate ``J dw/dt = torque - b w - Mc sgn(w) - T`` from the record's first state.

    Exact for a torque held over each sample; the speed stops at zero when it would change
    sign within a sample and sticks while the torque is within the Coulomb friction.  Returns
    the speed, or the position (trapezoidal integral from the first measured position).
    """
    j, b, mc, t_load = (float(v) for v in theta)
    dt = float(np.median(np.diff(rec.t)))
    a = math.exp(-b * dt / j)
    g = (1.0 - a) / b if b > 0 else dt / j
    w = 0.0 if position else float(rec.y[0])
    x = float(rec.y[0]) if position else 0.0
    out = [0.0] * len(rec.t)
    for k, torque in enumerate(rec.torque.tolist()):
        out[k] = x if position else w
        drive = torque - t_load
        if w > 0.0 or (w == 0.0 and drive > mc):
            sign = 1.0
        elif w < 0.0 or drive < -mc:
            sign = -1.0
        else:
            continue
        new = a * w + g * (drive - mc * sign)
        if new * sign < 0.0:
            new = 0.0
        x += 0.5 * dt * (w + new)
        w = new
    return np.asarray(out)


def fit_pct(y: np.ndarray, y_hat: np.ndarray) -> float:
    """Return MATLAB's fit percent ``100 (1 - |y - y_hat| / |y - mean(y)|)``."""
    return float(100.0 * (1.0 - np.linalg.norm(y - y_hat) / np.linalg.norm(y - np.mean(y))))


def _equation_error(recs: list[Rec], both: bool, position: bool) -> np.ndarray:
    """Least squares on ``torque = J dw + b w + Mc sgn(w) + T``, Savitzky-Golay derivatives."""
    from scipy.signal import savgol_filter
    rows, targets = [], []
    for rec in recs:
        dt = float(np.median(np.diff(rec.t)))
        window = max(11, int(0.02 / dt) | 1)
        order = 1 if position else 0
        w = savgol_filter(rec.y, window, 3, deriv=order, delta=dt)
        dw = savgol_filter(rec.y, window, 3, deriv=order + 1, delta=dt)
        moving = np.abs(w) > 0.05 * np.max(np.abs(w))
        columns = [dw, w, np.sign(w)] + ([np.ones_like(w)] if both else [])
        rows.append(np.column_stack(columns)[moving])
        targets.append(rec.torque[moving])
    theta = np.linalg.lstsq(np.vstack(rows), np.concatenate(targets), rcond=None)[0]
    j = abs(theta[0]) or 1.0
    b = abs(theta[1]) or j
    return np.array([j, b, abs(theta[2]), theta[3] if both else 0.0])


def peer_fit(recs: list[Rec], both: bool, position: bool) -> dict[str, Any]:
    """
    Fit the peer: a plain output-error fit with ``scipy.optimize.least_squares``.

    Parameters J, b, Mc (and T when both directions are present; on one direction Mc is that
    direction's total friction), started from the equation-error fit, scaled by it, residuals
    normalised by each record's spread; Gauss-Newton standard errors.
    """
    from scipy.optimize import least_squares
    start = time.perf_counter()
    theta0 = _equation_error(recs, both, position)
    scale = np.array([theta0[0], theta0[1], max(theta0[2], 1e-3 * theta0[1]),
                      max(theta0[2], abs(theta0[3]), 1e-3 * theta0[1])])
    free = 4 if both else 3
    spreads = [float(np.std(rec.y)) or 1.0 for rec in recs]

    def residual(p: np.ndarray) -> np.ndarray:
        theta = np.append(p * scale[:free], [0.0] * (4 - free))
        return np.concatenate([(simulate(theta, rec, position) - rec.y) / spread
                               for rec, spread in zip(recs, spreads)])

    lower = [1e-6, 0.0, 0.0, -np.inf][:free]
    p0 = np.clip(theta0[:free] / scale[:free], np.array(lower) + 1e-9, None)
    try:
        fit = least_squares(residual, p0, bounds=(lower, np.inf), x_scale='jac')
    except (ValueError, FloatingPointError, np.linalg.LinAlgError) as error:
        return {'status': f'failed: {error}', 'wall': time.perf_counter() - start}
    theta = np.append(fit.x * scale[:free], [0.0] * (4 - free))
    dof = max(fit.fun.size - free, 1)
    covariance = np.linalg.pinv(fit.jac.T @ fit.jac) * float(fit.fun @ fit.fun) / dof
    errors = np.sqrt(np.abs(np.diag(covariance))) * scale[:free]
    values = dict(zip(PARAMETERS, theta.tolist()))
    if not both:
        values['T'] = None
    return {'status': 'ok' if fit.success else f'not converged: {fit.message}',
            'theta': theta, 'values': values, 'stderr': dict(zip(PARAMETERS, errors.tolist())),
            'fit': float(np.mean([fit_pct(rec.y, simulate(theta, rec, position))
                                  for rec in recs])),
            'wall': time.perf_counter() - start}


def job_direction(ds: DataSet, job: Job) -> str:
    """Return 'pos', 'neg' or 'both': the directions the fitted records cover."""
    directions = {ds.records[name].direction for name in job.members}
    return directions.pop() if len(directions) == 1 else 'both'


def reference(ds: DataSet, key: str, direction: str) -> Optional[float]:
    """Return the reference of a parameter; on one direction Mc is compared with Mc +- T."""
    ref = ds.refs.get(key)
    if ref is None or direction == 'both':
        return ref
    if key == 'T':
        return None
    if key == 'Mc' and 'T' in ds.refs:
        return ref + ds.refs['T'] if direction == 'pos' else ref - ds.refs['T']
    return ref


def tool_values(result: dict[str, Any]) -> tuple[dict, dict]:
    """Return the tool's J, b, Mc and load torque T (load_torque or Coulomb asymmetry)."""
    parameters, stderr = result.get('parameters', {}), result.get('stderr', {})
    values = {key: parameters.get(key) for key in ('J', 'b', 'Mc')}
    errors = {key: stderr.get(key) for key in ('J', 'b', 'Mc')}
    values['T'] = None
    for effect in result.get('effects') or []:
        if effect['name'] == 'load_torque':
            values['T'] = effect['parameters'].get('torque_Nm')
        elif effect['name'] == 'coulomb_asymmetry' and values['T'] is None:
            values['T'] = effect['parameters'].get('delta_Nm')
    return values, errors


def _peer_validation(ds: DataSet, job: Job, peer: dict[str, Any]) -> dict[str, dict]:
    """Simulate the peer's parameters on the held-out records: fit % by group."""
    if 'theta' not in peer:
        return {}
    position = ds.output == 'position'
    return {group: {name: fit_pct(ds.records[name].y,
                                  simulate(peer['theta'], ds.records[name], position))
                    for name in names} for group, names in job.heldout.items()}


def evaluate(ds: DataSet, job: Job, work: str) -> dict[str, Any]:
    """Identify one job with the tool, validate it, fit the peer; return the row."""
    recs = [ds.records[name] for name in job.members]
    out = os.path.join(work, f'{ds.name}_{re.sub(r"[^A-Za-z0-9.]+", "_", job.label)}.json')
    run = run_cli(['identify', *[rec.path for rec in recs], *ds.reading,
                   '--torque-constant', f'{ds.torque_constant:.6g}', '--json', out])
    row: dict[str, Any] = {'ds': ds, 'job': job, 'run': run,
                           'samples': sum(len(rec.t) for rec in recs),
                           'direction': job_direction(ds, job), 'validate': {}, 'result': None}
    if run['rc'] == 0 and os.path.isfile(out):
        with open(out) as stream:
            row['result'] = json.load(stream)
        row['values'], row['stderr'] = tool_values(row['result'])
        row['validate'] = validate_groups(ds, out, job.heldout, work)
    row['peer'] = peer_fit(recs, row['direction'] == 'both', ds.output == 'position')
    row['peer_validate'] = _peer_validation(ds, job, row['peer'])
    log(f'{ds.name} {job.label}: exit {run["rc"]} in {run["wall"]:.1f} s '
        f'(CPU {run["cpu"]:.1f} s){", " + run["message"][:80] if run["message"] else ""}; '
        f'peer {row["peer"]["status"]} in {row["peer"]["wall"]:.1f} s')
    return row


def num(value: Optional[float], digits: int = 3) -> str:
    """Format a number compactly ('-' for none)."""
    if value is None or not np.isfinite(value):
        return '-'
    return f'{value:.{digits}g}'


def error_pct(value: Optional[float], ref: Optional[float]) -> Optional[float]:
    """Signed error of a value against its reference [%], or None."""
    if value is None or ref is None or not np.isfinite(value) or ref == 0:
        return None
    return 100.0 * (value - ref) / abs(ref)


def with_error(value: Optional[float], ref: Optional[float]) -> str:
    """Format ``value (error %)``."""
    error = error_pct(value, ref)
    return num(value) + ('' if error is None else f' ({error:+.0f} %)')


def warning_kind(text: str) -> str:
    """Return the kind of a warning: its first words, without file names and numbers."""
    text = re.sub(r'^\S+\.(?:mat|csv): ', '', shorten(text))
    words = [word for word in re.split(r'[\s()]+', text) if not re.search(r'\d', word)]
    return ' '.join(words[:5]).rstrip(':,;')


def warnings_short(result: Optional[dict[str, Any]]) -> str:
    """Return ``count: kind xN; kind`` for the warnings of a result."""
    if result is None:
        return '-'
    texts = result.get('warnings') or []
    kinds: dict[str, int] = {}
    for text in texts:
        kinds[warning_kind(text)] = kinds.get(warning_kind(text), 0) + 1
    parts = [kind + (f' x{count}' if count > 1 else '') for kind, count in kinds.items()]
    return f'{len(texts)}' + (': ' + '; '.join(parts) if parts else '')


def group_fits(fits: dict[str, dict]) -> str:
    """Format validation fit % by group: the median and the lowest."""
    parts = []
    for group, values in fits.items():
        if 'error' in values:
            parts.append(f'{group}: {values["error"][:60]}')
            continue
        array = np.array(list(values.values()), dtype=float)
        text = f'{group} {num(float(np.median(array)), 3)}'
        parts.append(text + (f' (min {num(float(array.min()), 3)})' if array.size > 1 else ''))
    return '; '.join(parts) or '-'


TOOL_HEADER = ('fit', 'records', 'samples', 'exit', 'J', 'b', 'Mc', 'T (load)', 'effects',
               'held-out NRMSE %', 'whole-record fit %', 'validate fit %', 'warnings',
               'wall s (CPU)')
PEER_HEADER = ('fit', 'J', 'b', 'Mc', 'T', 'fit % (fitted)', 'validate fit %', 'plausible',
               'wall s')


def row_label(row: dict[str, Any]) -> str:
    """Return the row's label."""
    return row['job'].label


def _mc_text(row: dict[str, Any], value: Optional[float], ref: Optional[float]) -> str:
    """Format Mc: F+ / F- for a direction's total friction, 'at 0' at its bound."""
    text = with_error(value, ref)
    missing = (row['result'] or {}).get('not_identifiable') or {}
    if 'Mc' in missing and 'bound' in missing['Mc']:
        return text + ' at 0'
    if row['direction'] != 'both':
        return text + (' F+' if row['direction'] == 'pos' else ' F-')
    return text


def tool_cells(row: dict[str, Any]) -> list[str]:
    """One row of the tool's table."""
    ds, run, result = row['ds'], row['run'], row['result']
    head = [row_label(row), str(len(row['job'].members)), str(row['samples'])]
    times = f'{run["wall"]:.1f} ({run["cpu"]:.1f})'
    if result is None:
        refusal = f'{run["rc"]}: {run["message"][:160]}'
        return head + [refusal] + ['-'] * 9 + [times]
    values = row['values']
    refs = {key: reference(ds, key, row['direction']) for key in PARAMETERS}
    effects = ', '.join(map(effect_text, result.get('effects') or [])) or '-'
    heldout = (result.get('error_after') or {}).get('speed_nrmse_pct')
    whole = [r['after']['whole_record'].get('speed_fit_pct')
             for r in (result.get('errors') or {}).get('records', [])]
    whole_mean = float(np.mean(whole)) if whole and None not in whole else None
    return head + ['0', with_error(values['J'], refs['J']), with_error(values['b'], refs['b']),
                   _mc_text(row, values['Mc'], refs['Mc']), with_error(values['T'], refs['T']),
                   effects, num(heldout), num(whole_mean), group_fits(row['validate']),
                   warnings_short(result), times]


def effect_text(effect: dict[str, Any]) -> str:
    """Format an effect with its parameters: ``name(key=value, ...)``."""
    values = ', '.join(f'{key}={num(value) if isinstance(value, (int, float)) else value}'
                       for key, value in (effect.get('parameters') or {}).items())
    return f'{effect["name"]}({values})'


def peer_plausible(row: dict[str, Any]) -> bool:
    """Say if the peer is plausible: J, b > 0 and within 2x of the references, fit >= 50 %."""
    peer = row['peer']
    if 'values' not in peer:
        return False
    for key in ('J', 'b'):
        value, ref = peer['values'][key], row['ds'].refs.get(key)
        if not value > 0 or (ref is not None and not 0.5 <= value / ref <= 2.0):
            return False
    return bool(peer['fit'] >= 50.0)


def peer_cells(row: dict[str, Any]) -> list[str]:
    """One row of the peer's table."""
    peer, ds = row['peer'], row['ds']
    if 'values' not in peer:
        return [row_label(row), peer['status'][:100]] + ['-'] * 6 + [f'{peer["wall"]:.1f}']
    values = peer['values']
    refs = {key: reference(ds, key, row['direction']) for key in PARAMETERS}
    mc = with_error(values['Mc'], refs['Mc'])
    if row['direction'] != 'both':
        mc += ' F+' if row['direction'] == 'pos' else ' F-'
    status = '' if peer['status'] == 'ok' else f' ({peer["status"][:40]})'
    return [row_label(row), with_error(values['J'], refs['J']),
            with_error(values['b'], refs['b']), mc, with_error(values['T'], refs['T']),
            num(peer['fit']), group_fits(row['peer_validate']),
            ('yes' if peer_plausible(row) else 'no') + status, f'{peer["wall"]:.1f}']


def markdown(header: tuple[str, ...], rows: list[list[str]]) -> list[str]:
    """Render a markdown table (cells with '|' escaped)."""
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    for cells in rows:
        lines.append('| ' + ' | '.join(cell.replace('|', '/') for cell in cells) + ' |')
    return lines


def max_z(entries: list[tuple[Optional[float], Optional[float]]]) -> Optional[float]:
    """Largest ``|a - b| / sqrt(sa^2 + sb^2)`` over the pairs with both known; None if none."""
    known = [(float(a), float(s)) for a, s in entries if a is not None and s is not None
             and np.isfinite([a, s]).all()]
    zs = []
    for i, (a, sa) in enumerate(known):
        for b, sb in known[i + 1:]:
            zs.append(abs(a - b) / math.hypot(sa, sb) if (sa or sb) else math.inf)
    return max(zs) if zs else None


def _entries(rows: list[dict[str, Any]], key: str, peer: bool) -> list[tuple]:
    """(value, stderr) of a parameter over rows, from the tool or from the peer."""
    entries = []
    for row in rows:
        source = row['peer'] if peer else row
        values, errors = source.get('values'), source.get('stderr')
        entries.append((values.get(key), errors.get(key)) if values and errors else
                       (None, None))
    return entries


def z_rows(rows: list[dict[str, Any]]) -> list[list[str]]:
    """Per family of disjoint subsets and parameter: values +- stderr and the largest z."""
    cells = []
    families = sorted({row['job'].family for row in rows if row['job'].family})
    for family in families:
        members = [row for row in rows if row['job'].family == family]
        for key in ('J', 'b', 'Mc'):
            text = []
            for peer in (False, True):
                entries = _entries(members, key, peer)
                text += ['; '.join(f'{num(v)} +- {num(s, 2)}' for v, s in entries),
                         num(max_z(entries), 2)]
            cells.append([f'{family} ({len(members)})', key] + text)
    return cells


Z_HEADER = ('disjoint subsets', 'parameter', 'tool: value +- stated stderr', 'tool max z',
            'peer: value +- Gauss-Newton stderr', 'peer max z')


def _errors(row: dict[str, Any], keys: tuple[str, ...]) -> dict[str, Optional[float]]:
    """Percent errors of the tool's parameters against the row's references."""
    if row['result'] is None:
        return dict.fromkeys(keys)
    return {key: error_pct(row['values'][key], reference(row['ds'], key, row['direction']))
            for key in keys}


def _failures(rows: list[dict[str, Any]], keys: tuple[str, ...], limit: float,
              z_limit: Optional[float] = None) -> list[str]:
    """
    Rows refused or with a parameter error beyond ``limit`` percent.

    With ``z_limit`` (issue 29), an error beyond ``limit`` counts only when it is also beyond
    ``z_limit`` stated standard errors (or these are unknown); the z is listed.
    """
    failed = []
    for row in rows:
        if row['result'] is None:
            failed.append(f'{row_label(row)}: refused ({row["run"]["message"][:70]})')
            continue
        bad = []
        for key, error in _errors(row, keys).items():
            z = None if z_limit is None else _stated_z(row, key)
            if error is None or (abs(error) > limit and (z_limit is None or z is None
                                                         or z > z_limit)):
                bad.append(f'{key} {"n/a" if error is None else f"{error:+.0f} %"}'
                           + ('' if z_limit is None else f' (z {num(z, 2)})'))
        if bad:
            failed.append(f'{row_label(row)}: ' + ', '.join(bad))
    return failed


def _stated_z(row: dict[str, Any], key: str) -> Optional[float]:
    """|value - reference| in the row's stated standard errors (None when unknown)."""
    value, stderr = row['values'].get(key), row['stderr'].get(key)
    ref = reference(row['ds'], key, row['direction'])
    return abs(value - ref) / stderr if None not in (value, stderr, ref) and stderr > 0 else None


def _friction_missing(row: dict[str, Any]) -> Optional[str]:
    """Why Coulomb friction and offset were not both found on a two-direction fit, or None."""
    if row['result'] is None:
        return f'{row_label(row)}: refused'
    missing = row['result'].get('not_identifiable') or {}
    if row['values']['T'] is None or 'Mc' in missing:
        return (f'{row_label(row)}: Mc {num(row["values"]["Mc"])}'
                f'{" (at its bound)" if "Mc" in missing else ""}, T {num(row["values"]["T"])}')
    return None


def goal_hsm150(rows: list[dict[str, Any]]) -> tuple[str, list[str]]:
    """
    J and b within 15 % (pairs, all 12); singles within 15 % or 3 stated stderrs (issue 29).

    Also: Coulomb and offset found on both directions; z <= 3 between disjoint subsets.
    """
    rows = [row for row in rows if row['ds'].name == 'hsm150']
    if not rows:
        return 'not run', []
    core = [row for row in rows if row['job'].kind in ('pair', 'all')]
    within = _failures(core, ('J', 'b'), 15.0)
    singles = [row for row in rows if row['job'].kind == 'single']
    within += _failures(singles, ('J', 'b'), 15.0, z_limit=3.0)
    core += singles
    both = [row for row in rows if row['direction'] == 'both']
    missing = [text for text in map(_friction_missing, both) if text]
    zs = {key: max_z(_entries([r for r in rows if r['job'].family == 'runs'], key, False))
          for key in ('J', 'b')}
    z_bad = [f'{k} z = {num(z, 2)}' for k, z in zs.items() if z is None or z > 3]
    details = [f'J and b within 15 % (pairs, all 12) or 3 stated standard errors (single '
               f'records) ({len(core) - len(within)}/{len(core)} fits): '
               + ('yes' if not within else 'no: ' + '; '.join(within)),
               f'Coulomb and offset found on both directions ({len(both) - len(missing)}/'
               f'{len(both)}): ' + ('yes' if not missing else 'no: ' + '; '.join(missing)),
               'z <= 3 between the runs (J, b): '
               + ('yes' if not z_bad else 'no: ' + ', '.join(z_bad))]
    return ('met' if not (within or missing or z_bad) else 'not met'), details


def goal_mech467(rows: list[dict[str, Any]]) -> tuple[str, list[str]]:
    """J and Coulomb within 30 % on every Part C record; validate on Part B reported."""
    part_c = [row for row in rows if row['ds'].name == 'mech467'
              and row['job'].kind == 'single' and row['job'].label.startswith('C/')]
    if not part_c:
        return 'not run', []
    failed = _failures(part_c, ('J', 'Mc'), 30.0)
    on_b = []
    for row in part_c:
        fits = row['validate'].get('Part B', {})
        on_b.append(next(iter(fits.values())) if fits and 'error' not in fits else None)
    reported = [v for v in on_b if v is not None]
    details = [f'J and Mc within 30 % ({len(part_c) - len(failed)}/{len(part_c)} Part C '
               'records): ' + ('yes' if not failed else 'no: ' + '; '.join(failed)),
               f'validate on Part B reported for {len(reported)}/{len(part_c)} Part C fits'
               + (f': position fit % median {num(float(np.median(reported)))}, '
                  f'{num(min(reported))} .. {num(max(reported))}' if reported else '')]
    met = not failed and len(reported) == len(part_c)
    return ('met' if met else 'not met'), details


def _off_by_2x(row: dict[str, Any]) -> list[str]:
    """Parameters more than 2x off their reference (or of the wrong sign)."""
    off = []
    for key in PARAMETERS:
        value, ref = row['values'][key], reference(row['ds'], key, row['direction'])
        if value is None or ref is None:
            continue
        ratio = value / ref
        if not 0.5 <= ratio <= 2.0:
            off.append(f'{key} {num(ratio, 2)}x')
    return off


def goal_honest(rows: list[dict[str, Any]]) -> tuple[str, list[str]]:
    """No refusal where the peer is plausible; nothing > 2x off without a warning."""
    refused = [f'{row["ds"].name} {row_label(row)}: {row["run"]["message"][:80]}'
               for row in rows if row['result'] is None and peer_plausible(row)]
    silent: list[str] = []
    said: list[str] = []
    for row in rows:
        if row['result'] is None:
            continue
        off = _off_by_2x(row)
        if off:
            warned = bool(row['result'].get('warnings'))
            target = said if warned else silent
            target.append(f'{row["ds"].name} {row_label(row)} ({", ".join(off)})')
    details = ['refusals of records the peer fits plausibly: '
               + ('none' if not refused else f'{len(refused)}: ' + '; '.join(refused)),
               'answers > 2x off a reference without any warning: '
               + ('none' if not silent else f'{len(silent)}: ' + '; '.join(silent)),
               f'(answers > 2x off with warnings, not counted: {len(said)}'
               + (': ' + '; '.join(said) if said else '') + ')']
    return ('met' if not (refused or silent) else 'not met'), details


def goal_time(rows: list[dict[str, Any]]) -> tuple[str, list[str]]:
    """Every identify run of up to 300k samples under 30 s (wall clock, and CPU beside)."""
    runs = [row for row in rows if row['samples'] <= 300_000]
    slow = [row for row in runs if row['run']['wall'] >= 30.0]
    slow_cpu = [row for row in slow if row['run']['cpu'] >= 30.0]
    details = [f'{len(runs) - len(slow)}/{len(runs)} runs under 30 s of wall-clock time, '
               f'{len(runs) - len(slow_cpu)}/{len(runs)} under 30 s of CPU']
    details += [f'slow: {row["ds"].name} {row_label(row)} ({row["samples"]} samples): '
                f'{row["run"]["wall"]:.1f} s (CPU {row["run"]["cpu"]:.1f} s)' for row in slow]
    if not runs:
        return 'not run', details
    if not slow:
        return 'met', details
    if not slow_cpu:
        return 'met on CPU time, not met on wall-clock time (load of the machine)', details
    return 'not met', details


GOALS = (
    ('HSM150: J and b within 15 % of the catalog for every opposite pair and all 12 together, '
     'every single record within 15 % or within 3 stated standard errors (issue 29); Coulomb '
     'and offset found when both directions are present; z <= 3 between disjoint subsets',
     goal_hsm150),
    ('MECH 467: J within 30 % of 7e-4 and Coulomb within 30 % of 0.22 for every Part C '
     'record; validate on Part B fit % reported', goal_mech467),
    ('No refusal of a record that a plain output-error fit identifies plausibly; no answer '
     'more than 2x off a reference without a warning', goal_honest),
    ('Any record up to 300k samples under 30 s', goal_time),
)

LEGEND = (
    'Columns.  *exit*: the exit code of `identify` (refusal text after it).  *J, b, Mc, T*: '
    'the value and its error against the reference in %; on one-direction fits Mc is the '
    "direction's total friction (F+ / F-, the tool's `combined.friction_torque_Nm`); *at 0*: "
    'Mc at its bound; *T*: the `load_torque` effect (or the `coulomb_asymmetry` delta) when '
    'found.  *held-out NRMSE %*: the headline `error_after.speed_nrmse_pct`; *whole-record '
    'fit %*: the mean over the fitted records of `errors.records[].after.whole_record.'
    'speed_fit_pct`; *validate fit %*: `dcmotor-id validate` of the result on records not '
    'fitted (speed fit % for HSM150, position fit % for MECH 467 and EMPS), the median and '
    'the lowest per group; *warnings*: the count and their kinds; *wall s (CPU)*: the whole '
    'process (imports included) as a user waits for it.  The peer: the plain scipy output-'
    'error fit on the same records (speed for HSM150, position for MECH 467 and EMPS), fit % '
    'on the fitted records, the same validation; *plausible*: J and b positive and within 2x '
    'of the references (where known), fit >= 50 %.  z: |a - b| / sqrt(sa^2 + '
    'sb^2) over the pairs of disjoint subsets, with the stated standard errors.  Round-3 '
    'tables: *(tool)* the value, its error against the reference in % and *se* its stated '
    'standard error relative to the value; *(regression)* the model-free regression on the '
    'same records.')


def goal_lines(rows: list[dict[str, Any]]) -> list[str]:
    """Return the summary block: every goal of issues 19 and 29, met or not, with details."""
    lines = ['## Goals of issues 19 and 29', '']
    for text, check in GOALS:
        status, details = check(rows)
        lines.append(f'- **{text}**: **{status}**')
        lines += [f'  - {detail}' for detail in details]
    return lines + ['']


def finding_lines(data_sets: list[DataSet], more: list[dict[str, Any]] = ()) -> list[str]:
    """Return the table of the reading attempts (files read as recorded, or the hand work)."""
    cells = [[f['data'], f['file'], f['attempt'], str(f['exit']), f['message']]
             for f in [f for ds in data_sets for f in ds.findings] + list(more)]
    return (['## Reading the files as recorded', ''] + markdown(
        ('data', 'file', 'reading options tried', 'exit', 'message'), cells) + [''])


def text_lines(rows: list[dict[str, Any]]) -> list[str]:
    """Return the refusal texts and every kind of warning with one example and its fits."""
    lines = []
    for row in rows:
        if row['result'] is None:
            lines.append(f'- refused, {row_label(row)}: exit {row["run"]["rc"]}, '
                         f'"{row["run"]["message"]}"')
        for group, fits in row['validate'].items():
            if 'error' in fits:
                lines.append(f'- validate failed, {row_label(row)} on {group}: '
                             f'"{fits["error"]}"')
    kinds: dict[str, tuple[str, list[str]]] = {}
    for row in rows:
        for text in (row['result'] or {}).get('warnings') or []:
            example, labels = kinds.setdefault(warning_kind(text), (shorten(text), []))
            if row_label(row) not in labels:
                labels.append(row_label(row))
    for kind, (example, labels) in kinds.items():
        lines.append(f'- warning "{kind}" ({len(labels)} fits: {", ".join(labels)}); e.g. '
                     f'"{example[:400]}"')
    return lines or ['- none']


def data_set_lines(ds: DataSet, rows: list[dict[str, Any]]) -> list[str]:
    """Return the section of one data set: the tool, the peer, disjoint subsets, texts."""
    lines = [f'## {ds.title}', '', ds.note, '', '### The tool (`identify`, then `validate`)',
             ''] + markdown(TOOL_HEADER, [tool_cells(row) for row in rows])
    lines += ['', '### The peer (plain scipy output-error fit)', '']
    lines += markdown(PEER_HEADER, [peer_cells(row) for row in rows])
    families = z_rows(rows)
    if families:
        lines += ['', '### Disjoint subsets: stated standard errors against the spread', '']
        lines += markdown(Z_HEADER, families)
    return lines + ['', '### Refusals and warnings, text', ''] + text_lines(rows) + ['']


# --- Round 3 (issue 29): a SysId log, a robot's wheel motors, a QUBE-Servo 2 teaching rig ----

SYSIDOPT_COMMIT = 'f8c2183'
WHEELS_COMMIT = '59fc082'
QUBE_COMMIT = '092cd65'
#: github BrOleg5/research-wheel-slippage, scripts/dc_motor_kalman_filter/scripts/
#: motor_parameters_without_integral.m: datasheet k_t (24 V, 0.86 A, 3600 rpm motor) and the
#: authors' greyest values (J common; b and the constant torque T_0 per motor).
WHEELS_K = 0.0514
WHEELS_REFS = {'1st': {'J': 1.1407e-6, 'b': 2.3685e-5, 'Mc': 0.0081312},
               '2nd': {'J': 1.1407e-6, 'b': 2.0285e-5, 'Mc': 0.0069712},
               '3rd': {'J': 1.1407e-6, 'b': 2.3637e-5, 'Mc': 0.0080917}}
WHEELS_FILE = 'scripts/dc_motor_kalman_filter/data/data_for_identification_without_integral.csv'
WHEELS_PERIOD_S = 0.03064
#: QUBE-Servo 2 (Quanser datasheet, in the repository's Simulation/Params/m0405_params.m):
#: Rm 8.4 Ohm, km = kt 0.042, rotor Jm 4e-6 kg m^2, hub Jh 6e-7 (the authors: 8.009e-6 for
#: both together).  kV = km + Rm b/km is at least km; kA = Rm J/km.
QUBE_KM = 0.042
QUBE_REFS = {'kV': QUBE_KM, 'kA': 8.4 * (4e-6 + 6e-7) / QUBE_KM}
QUBE_KA_AUTHORS = 8.4 * 8.009e-6 / QUBE_KM
QUBE_FILES = ('20220304_1224_no_pendulum_1V_squarewave_0p2Hz',
              '20220314_1509_no_pendulum_1V_exp01',
              '20220314_1526_no_pendulum_varin_exp02',
              '20220314_1536_no_pendulum_sweepsine_exp02')
QUBE_READING = ['--column', 't=time', '--column', 'voltage=voltage', '--column',
                'position=theta']
#: github MiamiBeachBots/base-bot: a 2023 FRC drivetrain's SysId data file (the sample layout of
#: SysId before 2024: time, left and right voltage, position, velocity, gyro angle and rate).
BASEBOT_COMMIT = '89a98a9'
BASEBOT_COLUMNS = {'left': (1, 5), 'right': (2, 6)}
#: github ryg-delta/SEED_Lab_SP24 (Colorado School of Mines SEED lab): one step of 200/255 of a
#: 7.6 V supply from rest per wheel motor, logged every 10 ms by the Arduino; the authors' first
#: order model (``Runmotorsim.m``): DC gain K 1.65 rad/(V s), sigma 5.4 1/s.
SEEDLAB_COMMIT = 'e61c0c4'
SEEDLAB_FOLDER = 'Demos/Matlab_Code/Experimental/Motors'
SEEDLAB_STEP_V = 7.6 * 200 / 255
SEEDLAB_K, SEEDLAB_SIGMA = 1.65, 5.4
SEEDLAB_REFS = {'kV': 1 / SEEDLAB_K, 'kA': 1 / (SEEDLAB_K * SEEDLAB_SIGMA)}


@dataclass
class Run3:
    """One default ``identify`` of a round-3 record: what the user ran and the references."""

    data: str
    label: str
    args: list[str]
    refs: dict[str, float]
    peer: Any
    note: str = ''


def sysid_ols(path: str, threshold: float = 0.1, columns: tuple[int, int] = (1, 3),
              to_rad: float = 1.0) -> dict[str, float]:
    """
    Return kS, kV, kA of SysId's least squares on a SysId JSON file (the authors' own method).

    As ``solve_eigen_sysid_ols`` of calcmogul/SysIdOpt ``src/main.cpp``: the acceleration
    ``(v[k+1] - v[k]) / T`` regressed on ``v[k]``, ``u[k]``, ``sgn v[k]`` over the samples moving
    faster than 0.1 units/s, ``T`` the mean step of those samples.  ``columns``: the sample's
    voltage and velocity columns (a drivetrain side's); ``to_rad``: radians per unit of the
    file (``2 pi / unitsPerRotation``), so that kV and kA come in V s/rad and V s^2/rad.
    """
    with open(path) as stream:
        data = json.load(stream)
    volt, vel = columns
    tests = [np.asarray(data[name], dtype=float) for name in
             ('fast-backward', 'fast-forward', 'slow-backward', 'slow-forward')]
    moving = [np.abs(test[:-1, vel]) >= threshold for test in tests]
    step = float(np.mean(np.concatenate([np.diff(test[:, 0])[m]
                                         for test, m in zip(tests, moving)])))
    rows = np.vstack([np.column_stack([test[:-1, vel] * to_rad, test[:-1, volt],
                                       np.sign(test[:-1, vel])])[m]
                      for test, m in zip(tests, moving)])
    accel = np.concatenate([(np.diff(test[:, vel] * to_rad) / step)[m]
                            for test, m in zip(tests, moving)])
    alpha, beta, gamma = np.linalg.lstsq(rows, accel, rcond=None)[0]
    return {'kS': -gamma / beta, 'kV': -alpha / beta, 'kA': 1.0 / beta}


def regression_peer(paths: list[str], options: dict[str, Any],
                    torque_constant: Optional[float]) -> dict[str, Any]:
    """
    Return the model-free regression on the records as the tool reads and prepares them.

    With a current: the regression floor of both equations (``pipeline/floor.py``) over the
    tests; without: the voltage-to-speed regression start (``estimators/voltage_speed.py``).
    """
    sys.path.insert(0, ROOT)
    from dcmotor_id.formats import read_records, ReadOptions
    from dcmotor_id.identification.estimators.voltage_speed import regression_start
    from dcmotor_id.identification.identify import prepare_records
    from dcmotor_id.identification.pipeline.floor import regression_floor
    from dcmotor_id.identification.pipeline.segments import split_tests
    try:
        records = read_records(paths, options=ReadOptions(**options),
                               mechanical_only=torque_constant is not None)
        tests = list(split_tests(prepare_records(records, torque_constant)).records)
        if torque_constant is None and all(rec.current is None for rec in tests):
            values = regression_start(tests)
            return {'values': values, 'usable': values['kV'] > 1e-6 and values['kA'] > 0}
        floor = regression_floor(tests, torque_constant)
    except Exception as error:  # the peer's failure is a finding, not a crash of the bench
        return {'values': {}, 'usable': False, 'error': f'{type(error).__name__}: {error}'}
    if floor is None:
        return {'values': {}, 'usable': False, 'error': 'too short'}
    positive = all(floor.parameters[key] > 0 for key in ('J', 'b') if key in floor.parameters)
    return {'values': dict(floor.parameters), 'usable': bool(floor.usable) and positive}


def sysidopt_runs(path: str, cache: str) -> list[Run3]:
    """calcmogul/SysIdOpt ``sysid_data.json``: given to ``identify`` as it comes."""
    repo = Repository(path, SYSIDOPT_COMMIT, os.path.join(cache, 'SysIdOpt'))
    file = repo.local('sysid_data.json')
    refs = sysid_ols(file)
    return [Run3('SysIdOpt', 'sysid_data.json (4 tests)', [file], refs,
                 lambda: regression_peer([file], {}, None),
                 note=f'github calcmogul/SysIdOpt at {repo.revision()}, `sysid_data.json`: a '
                      'WPILib SysId routine of a mechanism (Simple, Radians), 5 ms samples, '
                      "voltage and velocity, no current.  References: the authors' own SysId "
                      'least squares on the file (`solve_eigen_sysid_ols` of `src/main.cpp`, '
                      'recomputed here: kS {kS:.4g} V, kV {kV:.4g} V s/rad, kA {kA:.4g} V s^2/'
                      'rad).'.format(**refs))]


def _wheels_csv(repo: 'Repository', cache: str) -> tuple[str, str, str]:
    """Write the log as recorded, without its unit rows, and with the authors' signed current."""
    original = repo.local(WHEELS_FILE)
    with open(original) as stream:
        lines = stream.read().splitlines()
    clean = os.path.join(cache, 'wheels_without_unit_rows.csv')
    with open(clean, 'w') as stream:
        stream.write('\n'.join([lines[0]] + lines[3:]) + '\n')
    header = lines[0].rstrip(';').split(';')
    rows = np.array([line.rstrip(';').split(';') for line in lines[3:]], dtype=float)
    for number in ('1st', '2nd', '3rd'):
        speed = rows[:, header.index(f'{number} motor velocity')]
        rows[:, header.index(f'{number} motor current')] *= np.sign(speed)
    signed = os.path.join(cache, 'wheels_signed_current.csv')
    np.savetxt(signed, rows, delimiter=';', header=';'.join(header), comments='', fmt='%.9g')
    return original, clean, signed


def wheels_runs(path: str, cache: str) -> tuple[list[Run3], list[dict[str, Any]]]:
    """BrOleg5/research-wheel-slippage: the three wheel motors of an omni robot, one log."""
    repo = Repository(path, WHEELS_COMMIT, os.path.join(cache, 'wheels'))
    original, clean, signed = _wheels_csv(repo, os.path.join(cache, 'wheels'))
    note = (f'github BrOleg5/research-wheel-slippage at {repo.revision()}, `{WHEELS_FILE}`: '
            'the three wheel motors of an omnidirectional robot, speed steps both ways under '
            'their speed loops, 30.6 ms samples (stamps in ms), speed [rad/s] and current [A, '
            "logged as a magnitude], no voltage.  `--torque-constant 0.0514` (the motor's "
            "datasheet k_t).  References: the authors' greyest values "
            '(`scripts/dc_motor_kalman_filter/scripts/motor_parameters_without_integral.m`): '
            'J 1.1407e-6 kg m^2, b 2.3685e-5 / 2.0285e-5 / 2.3637e-5 N m s/rad and a constant '
            'torque T_0 (as Mc) 0.00813 / 0.00697 / 0.00809 N m.  The authors give the current '
            'the sign of the speed before fitting (`process_identification_dataset.m`): rows '
            '"sign of speed" do the same.  The speed reaches each new set-point within one '
            '30 ms sample (0 to 17-20 rad/s from one sample to the next), so no J is '
            "determined by this log: neither the authors' nor the regression's, nor the "
            "tool's, which says so (J not determined: J with the current at the start and at "
            'the end of each sample differs by 80-115 % (bench/inertia_results.md); its '
            "standard error that half range's upper bound, 100-160 % of J).")
    runs = []
    for number in ('1st', '2nd', '3rd'):
        columns = {'speed': f'{number} motor velocity', 'current': f'{number} motor current'}
        mapping = [item for channel, name in columns.items()
                   for item in ('--column', f'{channel}={name}')]
        args = ['--sample-period', f'{WHEELS_PERIOD_S:g}', *mapping,
                '--torque-constant', f'{WHEELS_K:g}']
        options = {'columns': columns, 'sample_period_s': WHEELS_PERIOD_S}
        for label, file in (('as logged', clean), ('sign of speed', signed)):
            runs.append(Run3('wheels', f'motor {number[0]}, {label}', [file, *args],
                             WHEELS_REFS[number],
                             (lambda f=file, o=options: regression_peer([f], o, WHEELS_K)),
                             note=note))
    findings = []
    timed = ['--column', 't=Time']
    for label, file, extra in (('original CSV', original, timed),
                               ('its two unit rows removed', clean, timed),
                               ('unit rows removed, as the refusal tells', clean,
                                ['--sample-period', f'{WHEELS_PERIOD_S:g}'])):
        run = run_cli(['identify', file, '--column', 'speed=1st motor velocity', '--column',
                       'current=1st motor current', '--torque-constant', f'{WHEELS_K:g}',
                       *extra, '--json', os.path.join(cache, 'finding.json')])
        findings.append({'data': 'wheels', 'file': os.path.basename(WHEELS_FILE),
                         'attempt': f'{label} ' + ' '.join(extra), 'exit': run['rc'],
                         'message': run['message'] or 'read'})
    return runs, findings


def qube_runs(path: str, cache: str) -> list[Run3]:
    """JackDelcaro/ACL_LABisca: a QUBE-Servo 2 without its pendulum, voltage and angle."""
    repo = Repository(path, QUBE_COMMIT, os.path.join(cache, 'qube'))
    note = (f'github JackDelcaro/ACL_LABisca at {repo.revision()}, `Data/Parsed_Data/*.mat`: a '
            'Quanser QUBE-Servo 2 teaching rig without its pendulum, 500 Hz, `voltage` [V] and '
            'the motor angle `theta` [rad], no current (voltage-to-speed model).  References: '
            'the datasheet (in `Simulation/Params/m0405_params.m`): km 0.042 V s/rad, so kV = '
            'km + Rm b/km >= 0.042 (b small: about 0.042); kA = Rm (Jm + Jh)/km = '
            f'{QUBE_REFS["kA"]:.3g} V s^2/rad with the datasheet rotor and hub inertias, '
            f"{QUBE_KA_AUTHORS:.3g} with the authors' identified 8.009e-6 kg m^2.  The "
            'record `1V_exp01` is one 1 V step from rest: it crashed the fit before '
            '(ZeroDivisionError), its regression gave kV 1e-9 (its lower clip), then both were '
            'refused (one level in one direction ties kS to kV); now both hold kS at 0 and give '
            'the apparent kV = u/w at the final speed (kV + kS/w) and kA (kA u/(u - kS)), kS '
            "named not identifiable and kV's, kA's standard errors reaching 0 (the record bounds "
            'kS only by the voltage).')
    runs = []
    for stem in QUBE_FILES:
        file = repo.local(f'Data/Parsed_Data/{stem}.mat')
        options = {'columns': {'t': 'time', 'voltage': 'voltage', 'position': 'theta'}}
        runs.append(Run3('QUBE-Servo 2', stem[14:], [file, *QUBE_READING], QUBE_REFS,
                         (lambda f=file, o=options: regression_peer([f], o, None)), note=note))
    return runs


def basebot_runs(path: str, cache: str) -> list[Run3]:
    """MiamiBeachBots/base-bot ``sysid_data.json``: a drivetrain's SysId log, each side."""
    repo = Repository(path, BASEBOT_COMMIT, os.path.join(cache, 'base-bot'))
    file = repo.local('sysid_data.json')
    with open(file) as stream:
        to_rad = 2 * math.pi / float(json.load(stream)['unitsPerRotation'])
    refs = {side: sysid_ols(file, columns=columns, to_rad=to_rad)
            for side, columns in BASEBOT_COLUMNS.items()}
    note = (f'github MiamiBeachBots/base-bot at {repo.revision()}, `sysid_data.json` (last '
            'changed in a024652, 2023): a WPILib SysId routine of an FRC drivetrain (Drivetrain, '
            "Meters, 0.4878 m per wheel revolution), 5 ms samples, each side's voltage, "
            'position and velocity, no current; the four tests (quasistatic ramps to 4.6 V, '
            'dynamic steps of 8.1-8.7 V, both ways).  Read as it comes with `--joint left|right`'
            " (the velocity in rad/s of the wheel).  References: SysId's own least squares on "
            'the file (as `solve_eigen_sysid_ols` of calcmogul/SysIdOpt, recomputed here per '
            'side): left kS {l[kS]:.4g} V, kV {l[kV]:.4g} V s/rad, kA {l[kA]:.4g} V s^2/rad; '
            "right kS {r[kS]:.4g}, kV {r[kV]:.4g}, kA {r[kA]:.4g}.  SysId's kA comes from the "
            'difference of successive 5 ms velocity samples; it is a reference, not the truth: in '
            'the dynamic tests the speed jumps from 0 to 2.3-2.9 m/s within 30 ms (the wheels '
            "slipping, or the drive's own ramp) and then climbs to about 5 m/s over 0.5 s (the "
            "robot's mass): two regimes, of which SysId's kA follows the first and an "
            'output-error fit the second.'
            ).format(l=refs['left'], r=refs['right'])
    return [Run3('FRC drivetrain SysId (base-bot)', f'sysid_data.json, {side} side',
                 [file, '--joint', side], refs[side],
                 (lambda s=side: regression_peer([file], {'joint': s}, None)), note=note)
            for side in BASEBOT_COLUMNS]


def _seedlab_csv(mat: str, cache: str) -> str:
    """Write a SEED lab log with the applied voltage in its voltage column (the log's reads 0)."""
    from scipy.io import loadmat
    data = np.asarray(loadmat(mat)['data'], dtype=float)
    out = os.path.join(cache, os.path.basename(mat).replace('.mat', '_with_voltage.csv'))
    np.savetxt(out, np.column_stack([data[:, 0], np.full(len(data), SEEDLAB_STEP_V),
                                     data[:, 3]]),
               delimiter=',', header='t,voltage,speed', comments='', fmt='%.9g')
    return out


def first_order_step(mat: str) -> dict[str, float]:
    """
    Return kV, kA of the authors' kS-free first-order model fitted to a SEED lab step.

    ``w(t) = (u / kV) (1 - exp(-t kV / kA))`` by ``scipy.optimize.curve_fit`` on the logged speed
    (``u`` the applied 5.96 V, ``t`` from the first sample): the plain regression a student
    runs, and what the record determines once kS is taken as 0.
    """
    from scipy.io import loadmat
    from scipy.optimize import curve_fit
    speed = np.asarray(loadmat(mat)['data'], dtype=float)[:, 3]
    time_s = np.arange(speed.size) * 0.01

    def response(t: np.ndarray, kv: float, ka: float) -> np.ndarray:
        return SEEDLAB_STEP_V / kv * (1.0 - np.exp(-t * kv / ka))
    (kv, ka), _ = curve_fit(response, time_s, speed, p0=(0.6, 0.1))
    return {'kV': float(kv), 'kA': float(ka)}


def seedlab_runs(path: str, cache: str) -> tuple[list[Run3], list[dict[str, Any]]]:
    """ryg-delta/SEED_Lab_SP24: one voltage step from rest per wheel motor, speed only."""
    repo = Repository(path, SEEDLAB_COMMIT, os.path.join(cache, 'seedlab'))
    note = (f'github ryg-delta/SEED_Lab_SP24 at {repo.revision()}, `{SEEDLAB_FOLDER}/'
            '{left,right}MotorData.mat`: a Colorado School of Mines SEED lab, each wheel '
            'gearmotor driven from rest by 200/255 of a 7.6 V supply (5.96 V, the comment of '
            '`Runmotorsim.m`), `data` = time [s], voltage, encoder counts, speed [rad/s] every '
            '10 ms for 2 s (its stamps repeat once and skip twice: `--sample-period 0.01`); the '
            "voltage column reads 0 throughout.  References: the authors' first-order model "
            f'(`Runmotorsim.m`: DC gain K {SEEDLAB_K} rad/(V s), sigma {SEEDLAB_SIGMA} 1/s), '
            f'so kV = 1/K = {SEEDLAB_REFS["kV"]:.3g} V s/rad and kA = 1/(K sigma) = '
            f'{SEEDLAB_REFS["kA"]:.3g} V s^2/rad (their model has no kS).  Rows "as logged": the '
            '.mat with its voltage column; "applied voltage": a CSV with 5.96 V in it.  One '
            'level in one direction cannot separate kS from kV: the tool and its regression hold '
            'kS at 0 (named not identifiable; kV the apparent u/w at the final speed, kA its '
            "time constant times it, their standard errors reaching 0), the authors' kS-free "
            'model; their first-order fit computed here (`first_order_step`, kS taken as 0) '
            'gives {fits}.')
    fits = {side: first_order_step(repo.local(f'{SEEDLAB_FOLDER}/{side}MotorData.mat'))
            for side in ('left', 'right')}
    note = note.replace('{fits}', '; '.join(
        f'{side} kV {fit["kV"]:.3g} ({error_pct(fit["kV"], SEEDLAB_REFS["kV"]):+.0f} %), kA '
        f'{fit["kA"]:.3g} ({error_pct(fit["kA"], SEEDLAB_REFS["kA"]):+.0f} %)'
        for side, fit in fits.items()))
    runs, findings = [], []
    for side in ('left', 'right'):
        mat = repo.local(f'{SEEDLAB_FOLDER}/{side}MotorData.mat')
        csv = _seedlab_csv(mat, os.path.dirname(mat))
        logged = ['--sample-period', '0.01', '--column', 'voltage=data:2', '--column',
                  'speed=data:4']
        options = {'sample_period_s': 0.01, 'columns': {'voltage': 'data:2', 'speed': 'data:4'}}
        runs.append(Run3('SEED lab step', f'{side} motor, as logged', [mat, *logged],
                         SEEDLAB_REFS, (lambda m=mat, o=options: regression_peer([m], o, None)),
                         note=note))
        runs.append(Run3('SEED lab step', f'{side} motor, applied voltage',
                         [csv, '--sample-period', '0.01'], SEEDLAB_REFS,
                         (lambda c=csv: regression_peer([c], {'sample_period_s': 0.01}, None)),
                         note=note))
        if side == 'left':
            extra = ['--column', 't=data:1', '--column', 'voltage=data:2', '--column',
                     'speed=data:4']
            run = run_cli(['identify', mat, *extra])
            findings.append({'data': 'SEED lab step', 'file': os.path.basename(mat),
                             'attempt': 'the .mat with its time column ' + ' '.join(extra),
                             'exit': run['rc'], 'message': run['message'] or 'read'})
    return runs, findings


def evaluate3(run: Run3, work: str) -> dict[str, Any]:
    """Run the default ``identify`` of one round-3 record and its peer; return the row."""
    out = os.path.join(work, 'r3_' + re.sub(r'[^A-Za-z0-9.]+', '_', run.data + run.label)
                       + '.json')
    cli = run_cli(['identify', *run.args, '--json', out])
    result = None
    if cli['rc'] == 0 and os.path.isfile(out):
        with open(out) as stream:
            result = json.load(stream)
    peer = run.peer()
    log(f'{run.data} {run.label}: exit {cli["rc"]} in {cli["wall"]:.1f} s '
        f'(CPU {cli["cpu"]:.1f} s){", " + cli["message"][:80] if cli["message"] else ""}')
    return {'run': run, 'cli': cli, 'result': result, 'peer': peer}


def _cell(values: dict[str, Any], key: str, ref: Optional[float],
          stderr: Optional[dict[str, Any]] = None) -> str:
    """Format a value and its error against a reference (and its stated standard error)."""
    value = values.get(key)
    text = with_error(None if value is None else float(value), ref)
    stated = (stderr or {}).get(key)
    if value is None or stated is None or not float(value):
        return text
    return f'{text} se {100 * float(stated) / abs(float(value)):.2g} %'


def robot_log_lines(rows: list[dict[str, Any]]) -> list[str]:
    """Return the section of the round-3 records: the tool and its regression, side by side."""
    lines = []
    for data in dict.fromkeys(row['run'].data for row in rows):
        group = [row for row in rows if row['run'].data == data]
        keys = [key for key in ('Ra', 'CPhi', 'J', 'b', 'Mc', 'kS', 'kV', 'kA')
                if any(key in row['run'].refs for row in group)]
        lines += [f'## {data}', '', group[0]['run'].note, '']
        cells = []
        for row in group:
            refs, result, cli = row['run'].refs, row['result'], row['cli']
            tool = (result or {}).get('parameters') or {}
            head = [row['run'].label,
                    '0' if result else f'{cli["rc"]}: {cli["message"][:140]}']
            peer = row['peer']
            peer_text = ('plausible' if peer['usable'] else 'not plausible'
                         ) + (f' ({peer["error"][:60]})' if peer.get('error') else '')
            stated = (result or {}).get('stderr') or {}
            cells.append(head + [_cell(tool, key, refs.get(key), stated) for key in keys]
                         + [_cell(peer['values'], key, refs.get(key)) for key in keys]
                         + [peer_text, warnings_short(result),
                            f'{cli["wall"]:.1f} ({cli["cpu"]:.1f})'])
        header = (('record', 'exit') + tuple(f'{key} (tool)' for key in keys)
                  + tuple(f'{key} (regression)' for key in keys)
                  + ('regression', 'warnings', 'wall s (CPU)'))
        lines += markdown(header, cells) + ['']
    return lines


#: Warnings that say nothing of the values: the one every voltage-to-speed result carries, and
#: the note that a record's tests were fitted as separate records.
STANDARD_WARNING = ('no current in the records', 'the segment column marks the tests')


def _farther(row: dict[str, Any]) -> list[str]:
    """Parameters the tool has farther from their reference than the regression has."""
    tool = (row['result'] or {}).get('parameters') or {}
    peer = row['peer']['values']
    out = []
    for key, ref in row['run'].refs.items():
        mine, theirs = error_pct(tool.get(key), ref), error_pct(peer.get(key), ref)
        if mine is not None and theirs is not None and abs(mine) > abs(theirs) + 5.0:
            out.append(f'{key} {mine:+.0f} % against {theirs:+.0f} %')
    return out


def goal_robot_logs(rows: list[dict[str, Any]]) -> list[str]:
    """
    Return the goals of issue 29 on the round-3 records, met or not, per record.

    No refusal where the regression is plausible; no answer farther from a reference than the
    regression's (by more than 5 points) without a warning beyond the standard ones
    (:data:`STANDARD_WARNING`).
    """
    refused = [f'{row["run"].data} {row["run"].label}' for row in rows
               if row['result'] is None and row['peer']['usable']]
    silent, said = [], []
    for row in rows:
        farther = _farther(row) if row['result'] else []
        if farther:
            kinds = [text for text in row['result'].get('warnings') or []
                     if not text.startswith(STANDARD_WARNING)]
            (said if kinds else silent).append(
                f'{row["run"].data} {row["run"].label} ({", ".join(farther)})')
    return ['## Goals of issue 29 on the round-3 records', '',
            '- refusals where the regression gives a plausible answer: '
            + ('none' if not refused else f'{len(refused)}: ' + '; '.join(refused)),
            "- answers farther from a reference than the regression's, without a warning: "
            + ('none' if not silent else f'{len(silent)}: ' + '; '.join(silent)),
            '- (the same with a warning: ' + ('none' if not said else '; '.join(said)) + ')',
            '']


def cpu_seconds() -> float:
    """Return the CPU seconds of this process and of the processes it ran."""
    return sum(usage.ru_utime + usage.ru_stime for usage in (
        resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)))


def code_version() -> str:
    """Return the commit of this checkout (and whether the package has local changes)."""
    def git(*args: str) -> str:
        done = subprocess.run(['git', '-C', ROOT, *args], capture_output=True, text=True)
        return done.stdout.strip() if done.returncode == 0 else ''
    commit = git('rev-parse', '--short', 'HEAD') or 'unknown'
    package = git('log', '-1', '--format=%h', '--', 'dcmotor_id') or 'unknown'
    dirty = git('status', '--porcelain', '--', 'dcmotor_id')
    return (f'{commit} (dcmotor_id/ last changed in {package}'
            + (', with local changes)' if dirty else ')'))


def public_command(args: argparse.Namespace) -> str:
    """Return the command line, with the data directories named as in the set-up."""
    parts = ['.venv/bin/python', 'bench/bench_real.py']
    for option, value in (('--hsm150', 'HSM150-data' if args.hsm150 else None),
                          ('--mech467', 'mech467' if args.mech467 else None),
                          ('--sysidopt', 'SysIdOpt' if args.sysidopt else None),
                          ('--wheels', 'research-wheel-slippage' if args.wheels else None),
                          ('--qube', 'ACL_LABisca' if args.qube else None),
                          ('--basebot', 'base-bot' if args.basebot else None),
                          ('--seedlab', 'SEED_Lab_SP24' if args.seedlab else None),
                          ('--emps', '../shared/data/emps' if args.emps else None),
                          ('--only', args.only), ('--out', args.out)):
        if value:
            parts += [option, value]
    if args.quick:
        parts.append('--quick')
    if args.label != DEFAULT_LABEL:
        parts += ['--label', f"'{args.label}'"]
    return ' '.join(parts)


DEFAULT_LABEL = 'a run of the code at the commit below'


def parse(argv: Optional[list[str]]) -> argparse.Namespace:
    """Parse the command line of the benchmark."""
    parser = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    parser.add_argument('--hsm150', metavar='DIR', help='HSM150-data (work tree or bare clone)')
    parser.add_argument('--mech467', metavar='DIR', help='mech467 (work tree or bare clone)')
    parser.add_argument('--emps', metavar='DIR', default=os.environ.get('EMPS_DATA_DIR'),
                        help='directory of DATA_EMPS.mat (default $EMPS_DATA_DIR)')
    parser.add_argument('--sysidopt', metavar='DIR', help='calcmogul/SysIdOpt (work tree or '
                        'bare clone): its SysId JSON log')
    parser.add_argument('--wheels', metavar='DIR', help='BrOleg5/research-wheel-slippage (work '
                        'tree or bare clone): the wheel motors of a robot')
    parser.add_argument('--qube', metavar='DIR', help='JackDelcaro/ACL_LABisca (work tree or '
                        'bare clone): a QUBE-Servo 2 without its pendulum')
    parser.add_argument('--basebot', metavar='DIR', help='MiamiBeachBots/base-bot (work tree or '
                        "bare clone): an FRC drivetrain's SysId log")
    parser.add_argument('--seedlab', metavar='DIR', help='ryg-delta/SEED_Lab_SP24 (work tree or '
                        'bare clone): one voltage step from rest per wheel motor')
    parser.add_argument('--only', choices=('hsm150', 'mech467', 'emps', 'sysidopt', 'wheels',
                                           'qube', 'basebot', 'seedlab'))
    parser.add_argument('--quick', action='store_true', help='a subset of the fits')
    parser.add_argument('--out', metavar='FILE.md', help='also write the report here')
    parser.add_argument('--label', default=DEFAULT_LABEL, help='what this run is, for the title')
    parser.add_argument('--work', metavar='DIR', help='keep the JSON results and extracted '
                        'files here (default: a temporary directory)')
    return parser.parse_args(argv)


def data_sets(args: argparse.Namespace, work: str) -> tuple[list[DataSet], list[str]]:
    """Build the data sets asked for; return them and the notes on those not run."""
    built, skipped = [], []
    makers = (('hsm150', args.hsm150, lambda: hsm150_set(args.hsm150, work, args.quick)),
              ('mech467', args.mech467, lambda: mech467_set(args.mech467, work, args.quick)),
              ('emps', args.emps, lambda: emps_set(args.emps, args.quick)))
    for name, given, make in makers:
        if asked(args, name, given, skipped):
            built.append(make())
    return built, skipped


def asked(args: argparse.Namespace, name: str, given: str | None, skipped: list[str]) -> bool:
    """Whether the data set ``name`` is to be run (else the reason goes into ``skipped``)."""
    if args.only and args.only != name:
        return False
    if not given:
        skipped.append(f'{name}: not run (pass --{name} DIR)')
        return False
    log(f'{name}: reading the records')
    return True


def robot_log_runs(args: argparse.Namespace, work: str,
                   skipped: list[str]) -> tuple[list[Run3], list[dict[str, Any]]]:
    """Build the robot and lab log records asked for; return them and what reading them found."""
    runs: list[Run3] = []
    findings: list[dict[str, Any]] = []
    makers = {'sysidopt': lambda given: (sysidopt_runs(given, work), []),
              'wheels': lambda given: wheels_runs(given, work),
              'qube': lambda given: (qube_runs(given, work), []),
              'basebot': lambda given: (basebot_runs(given, work), []),
              'seedlab': lambda given: seedlab_runs(given, work)}
    for name, make in makers.items():
        given = getattr(args, name)
        if not asked(args, name, given, skipped):
            continue
        more, found = make(given)
        runs, findings = runs + more, findings + found
    return runs, findings


def report(args: argparse.Namespace, sets: list[DataSet], rows: list[dict[str, Any]],
           skipped: list[str], load: tuple[float, ...], setup: dict[str, Any],
           robot_logs: tuple[list, list] = ([], [])) -> str:
    """Return the whole markdown report; ``robot_logs`` holds its rows and reading findings."""
    import numpy
    import scipy
    end = os.getloadavg()
    lines = [f'# Real recordings: the scorecard of issue 19 ({args.label})', '',
             f'Command: `{public_command(args)}`  ', f'Code: commit {code_version()}  ',
             f'Machine: {os.cpu_count()} CPUs, Python {sys.version.split()[0]}, numpy '
             f'{numpy.__version__}, scipy {scipy.__version__}; load average (1, 5, 15 min) at '
             f'the start {", ".join(f"{v:.2f}" for v in load)}, at the end '
             f'{", ".join(f"{v:.2f}" for v in end)}  ',
             f'Run time: {time.perf_counter() - START:.0f} s wall clock, {cpu_seconds():.0f} s CPU'
             + (' (--quick)' if args.quick else '') + '  ',
             f'Set-up before the first fit: `python -m dcmotor_id.cli.warmup` (as `make demo` '
             f'installs), exit {setup["rc"]}, {setup["wall"]:.0f} s wall clock, '
             f'{setup["cpu"]:.0f} s CPU (in no row)', '']
    lines += [f'- {text}' for text in skipped] + ([''] if skipped else [])
    lines += goal_lines(rows) + (goal_robot_logs(robot_logs[0]) if robot_logs[0] else [])
    lines += finding_lines(sets, robot_logs[1]) + [LEGEND, '']
    for ds in sets:
        lines += data_set_lines(ds, [row for row in rows if row['ds'] is ds])
    return '\n'.join(lines + robot_log_lines(robot_logs[0]))


def main(argv: Optional[list[str]] = None) -> int:
    """Run the scorecard; print the report (and write it with --out)."""
    args = parse(argv)
    load = os.getloadavg()
    work = args.work or tempfile.mkdtemp(prefix='bench_real_')
    try:
        sets, skipped = data_sets(args, work)
        robot_runs, robot_findings = robot_log_runs(args, work, skipped)
        setup = warm_up()
        rows = []
        for ds in sets:
            for number, job in enumerate(ds.jobs, 1):
                log(f'{ds.name} {number}/{len(ds.jobs)}: {job.label}')
                rows.append(evaluate(ds, job, work))
        rows3 = [evaluate3(run, work) for run in robot_runs]
        text = report(args, sets, rows, skipped, load, setup, (rows3, robot_findings))
    finally:
        if not args.work:
            shutil.rmtree(work, ignore_errors=True)
    emit(text, args.out)
    return 0


def emit(text: str, out: str | None) -> None:
    """Print the report and, with ``--out``, write it to that file."""
    print(text)
    if out:
        with open(out, 'w') as stream:
            stream.write(text + '\n')


if __name__ == '__main__':
    sys.exit(main())
