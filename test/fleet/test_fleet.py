"""Fleet mode: discovery, grouping by motor, the Dask job, the Parquet history, the report."""

import math
import os
import shutil

import numpy as np
import pyarrow as pa
import pytest

from dcmotor_id.cli.main import main
from dcmotor_id.fleet import (find_sources, FleetOptions, known_sources, motor_streams,
                              namespace_of, read_history, run_fleet, SCHEMA, Source)
from dcmotor_id.fleet.history import result_row, write_rows
from dcmotor_id.fleet.simulated import DAY_NS, EPOCH_NS, make_fleet, write_recording
from dcmotor_id.fleet.trends import detect_changes, effect_alarms
from dcmotor_id.formats.bag import FLOAT64_TYPE
from dcmotor_id.formats.batch import BATCH_TYPE
from dcmotor_id.reports.fleet import write_fleet_report

OPTIONS = FleetOptions(discover=False, window_s=1.0, min_window_s=0.5)


def test_namespace_of():
    assert namespace_of('/robot7/left/voltage') == 'robot7/left'
    assert namespace_of('/voltage') == ''
    assert namespace_of('drive/speed') == 'drive'


def test_grouping_by_namespace():
    topics = {'/robot7/left/voltage': FLOAT64_TYPE, '/robot7/left/current': FLOAT64_TYPE,
              '/robot7/left/speed': FLOAT64_TYPE, '/robot7/right/current': FLOAT64_TYPE,
              '/robot7/right/speed': FLOAT64_TYPE, '/robot8/samples': BATCH_TYPE,
              '/robot9/voltage': FLOAT64_TYPE, '/rosout': 'rcl_interfaces/msg/Log',
              '/robot7/left/temperature': FLOAT64_TYPE}
    source = Source('/data/fleet/site1/bag_0', '/data/fleet', 'bag')
    motors = motor_streams(source, topics)
    assert sorted(motors) == ['robot7/left', 'robot7/right', 'robot8']
    assert motors['robot7/left'] == {'voltage': '/robot7/left/voltage',
                                     'current': '/robot7/left/current',
                                     'speed': '/robot7/left/speed',
                                     'samples': '/robot7/left/samples'}
    # absent channels are named absolutely in the motor's own namespace: never another's
    assert motors['robot7/right']['voltage'] == '/robot7/right/voltage'
    assert motors['robot8']['samples'] == '/robot8/samples'
    # topics without a namespace: the motor is named by the recording's place
    plain = {'/voltage': FLOAT64_TYPE, '/current': FLOAT64_TYPE, '/speed': FLOAT64_TYPE}
    assert list(motor_streams(source, plain)) == ['site1']
    assert list(motor_streams(source, plain, 'path')) == ['site1']
    assert list(motor_streams(source, plain, r'fleet/(\w+)/')) == ['site1']
    assert list(motor_streams(source, plain, r'(?P<motor>bag_\d+)')) == ['bag_0']


def _fleet(directory, motors=2, recordings=2, duration_s=2.0):
    paths = []
    for motor in make_fleet(motors, aging_share=0.0):
        for recording in range(recordings):
            paths.append(write_recording(str(directory), motor, recording, recordings,
                                         duration_s=duration_s, seed=recording))
    return paths


def test_find_sources(tmp_path):
    bags = _fleet(tmp_path / 'fleet', motors=1, recordings=1, duration_s=0.2)
    bare = tmp_path / 'fleet' / 'loose' / 'copy.mcap'
    bare.parent.mkdir()
    shutil.copy(os.path.join(bags[0], os.path.basename(bags[0]) + '.mcap'), bare)
    (tmp_path / 'fleet' / 'loose' / 'run.csv').write_text('t,voltage,current,speed\n')
    # every format the readers know is found (the fleet once looked for bags and CSV only)
    (tmp_path / 'fleet' / 'loose' / 'run.mat').write_bytes(b'')
    (tmp_path / 'fleet' / 'loose' / 'run.parquet').write_bytes(b'')
    (tmp_path / 'fleet' / 'loose' / 'RUN2.PQ').write_bytes(b'')
    (tmp_path / 'fleet' / '.hidden').mkdir()
    (tmp_path / 'fleet' / '.hidden' / 'x.csv').write_text('t\n')
    (tmp_path / 'fleet' / '.partial_m000').mkdir()
    (tmp_path / 'fleet' / 'notes.txt').write_text('not a recording')
    found = find_sources([str(tmp_path / 'fleet')])
    assert [(os.path.relpath(s.path, tmp_path), s.kind) for s in found] == [
        ('fleet/loose/RUN2.PQ', 'parquet'), ('fleet/loose/copy.mcap', 'bag'),
        ('fleet/loose/run.csv', 'csv'), ('fleet/loose/run.mat', 'mat'),
        ('fleet/loose/run.parquet', 'parquet'), ('fleet/m000/rec_00', 'bag')]
    assert found[-1].relative_dir == 'm000'


@pytest.fixture(scope='module')
def client():
    distributed = pytest.importorskip('distributed')
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                       dashboard_address='127.0.0.1:0')
    with distributed.Client(cluster) as connected:
        yield connected
    cluster.close()


def test_fleet_job_history_and_idempotence(tmp_path, client):
    fleet = tmp_path / 'fleet'
    bags = _fleet(fleet)
    broken = fleet / 'm001' / 'broken.mcap'
    broken.write_bytes(b'\x89MCAP0\r\n' + os.urandom(300))
    history_dir = str(tmp_path / 'history')
    summary = run_fleet([str(fleet)], history_dir, OPTIONS, client=client)
    assert (summary.found, summary.skipped, summary.done) == (5, 0, 5)
    assert summary.windows == 8 and summary.failures == 1
    table = read_history(history_dir)
    for field in SCHEMA:
        assert table.schema.field(field.name).type == field.type, field.name
    rows = table.to_pylist()
    ok = [row for row in rows if row['status'] == 'ok']
    assert len(ok) == 8 and sorted({row['motor_id'] for row in ok}) == ['m000', 'm001']
    # the corrupt bag is one error row saying why; the others all completed
    failed = [row for row in rows if row['status'] == 'error']
    assert len(failed) == 1 and failed[0]['source_bag'] == str(broken)
    assert 'cannot open' in failed[0]['error'] and failed[0]['window_index'] == -1
    assert failed[0]['motor_id'] == ''
    first = [row for row in ok if row['source_bag'] == bags[1]]
    assert [row['window_index'] for row in sorted(first, key=lambda r: r['window_index'])] \
        == [0, 1]
    for row in first:
        assert row['window_start_ns'] >= EPOCH_NS + DAY_NS
        assert row['window_end_ns'] - row['window_start_ns'] == 999_000_000
        assert row['n_samples'] == 1000 and math.isclose(row['sample_period_s'], 1e-3)
        assert row['Ra'] > 0 and row['Ra_stderr'] > 0 and row['method'] == 'refined'
        assert row['error_after_current_nrmse_pct'] is not None
        assert row['package_version'] and row['run_id'] and row['worker']
    # a re-run skips every recording already there but retries the one that failed (issue
    # 21: it may have been repaired); --no-retry-errors skips it too; --force redoes them all
    assert known_sources(history_dir) == set(bags)
    assert known_sources(history_dir, retry_errors=False) == set(bags) | {str(broken)}
    files = sorted(os.listdir(history_dir))
    skipping = run_fleet([str(fleet)], history_dir, OPTIONS, client=client,
                         retry_errors=False)
    assert (skipping.skipped, skipping.done) == (5, 0)
    assert sorted(os.listdir(history_dir)) == files
    again = run_fleet([str(fleet)], history_dir, OPTIONS, client=client)
    assert (again.skipped, again.done, again.failures) == (4, 1, 1)
    assert len(os.listdir(history_dir)) == len(files) + 1
    forced = run_fleet([bags[0]], history_dir, OPTIONS, client=client, force=True)
    assert forced.done == 1 and forced.windows == 2
    assert read_history(history_dir).num_rows == len(rows)
    assert read_history(history_dir, latest=False).num_rows == len(rows) + 3


def test_new_result_keys_reach_the_history(tmp_path):
    base = {'parameters': {'Ra': 1.0}, 'stderr': {'Ra': 0.1}, 'method': 'refined',
            'effects': [{'name': 'load_torque', 'parameters': {'torque_Nm': 0.3}}],
            'error_before': {'current_nrmse_pct': 2.0, 'speed_nrmse_pct': 3.0},
            'error_after': {'current_nrmse_pct': 1.0, 'speed_nrmse_pct': 1.5},
            'unexplained': False, 'discovery': {'rounds': []}}
    old = dict(result_row(base), motor_id='m', source_bag='/a', run_id='r1')
    write_rows(str(tmp_path), [old], 'r1')
    newer = dict(base, warnings=['few reversals'], not_identifiable=['La'],
                 stderr_model='sandwich', uncertainty_method='bootstrap')
    row = dict(result_row(newer), motor_id='m', source_bag='/b', run_id='r2')
    assert row['warnings'] == ['few reversals'] and row['not_identifiable'] == '["La"]'
    assert row['effects'] == [{'name': 'load_torque', 'parameters': '{"torque_Nm": 0.3}'}]
    write_rows(str(tmp_path), [row], 'r2')
    table = read_history(str(tmp_path), latest=False)
    assert table.schema.field('stderr_model').type == pa.string()
    by_bag = {item['source_bag']: item for item in table.to_pylist()}
    assert by_bag['/a']['stderr_model'] is None and by_bag['/b']['stderr_model'] == 'sandwich'
    assert by_bag['/b']['error_before_speed_nrmse_pct'] == 3.0 and 'discovery' not in by_bag['/b']


def test_change_detector():
    rng = np.random.default_rng(1)
    times = np.arange(12) * 1e9
    steady = [(t, 1.0 + 0.001 * rng.normal(), 0.001) for t in times]
    assert detect_changes({'Ra': steady}) == []
    rising = [(t, value * (1.0 + (0.1 * (k - 3) if k >= 4 else 0.0)), stderr)
              for k, (t, value, stderr) in enumerate(steady)]
    alarms = detect_changes({'Ra': rising, 'b': steady})
    assert [alarm.name for alarm in alarms] == ['Ra']
    assert alarms[0].level == 'ERROR' and alarms[0].since_s == 4e9 and alarms[0].raised == 5e9
    assert alarms[0].change_pct == pytest.approx(80.0, abs=1.0)
    # significant but below 5 %: no alarm
    small = [(t, value * (1.02 if k >= 4 else 1.0), stderr)
             for k, (t, value, stderr) in enumerate(steady)]
    assert detect_changes({'Ra': small}) == []
    effects = [(t, {'load_torque': 0.3} if k >= 6 else {}) for k, t in enumerate(times)]
    found = effect_alarms(effects)
    assert [alarm.name for alarm in found] == ['effect load_torque']
    assert found[0].since_s == 6e9 and found[0].value == 0.3
    assert effect_alarms([(t, {'load_torque': 0.3}) for t in times]) == []


def _synthetic_history(directory):
    rows = []
    for motor, aging in (('site/m1', False), ('site/m2', True)):
        for k in range(8):
            change = 1.0 + (0.08 * (k // 2) if aging else 0.0)
            values = {'Ra': 1.6 * change, 'La': 0.016, 'CPhi': 0.7, 'J': 0.0315,
                      'b': 0.3 * change, 'Mc': 1.0}
            effects = [{'name': 'load_torque', 'parameters': {'torque_Nm': 0.3}}] \
                if aging and k >= 4 else []
            result = {'parameters': values, 'stderr': {name: 1e-3 * value for name, value
                                                       in values.items()},
                      'method': 'refined', 'effects': effects,
                      'error_before': {'current_nrmse_pct': 2.0, 'speed_nrmse_pct': 3.0},
                      'error_after': {'current_nrmse_pct': 1.0, 'speed_nrmse_pct': 1.0},
                      'unexplained': False}
            rows.append(dict(result_row(result), motor_id=motor, source_bag=f'/{motor}/{k // 2}',
                             window_index=k % 2, window_start_ns=EPOCH_NS + k * DAY_NS // 2,
                             window_end_ns=EPOCH_NS + k * DAY_NS // 2 + 10 ** 10,
                             run_id='r', processed_at=None))
    rows.append({'status': 'error', 'error': 'cannot open as a rosbag2 bag', 'motor_id': '',
                 'source_bag': '/broken.mcap', 'window_index': -1, 'run_id': 'r'})
    write_rows(str(directory), rows, 'r')


def test_report_page(tmp_path):
    _synthetic_history(tmp_path / 'history')
    page = write_fleet_report(str(tmp_path / 'history'), str(tmp_path / 'report'))
    text = open(page, encoding='utf-8').read()
    names = os.listdir(tmp_path / 'report')
    assert {'index.html', 'overview.png', 'motor_site_m1.png', 'motor_site_m2.png'} <= set(names)
    # the overview lists the changed motor first, with its alarms
    assert text.index('href="#site_m2"') < text.index('href="#site_m1"')
    assert 'Ra +24.0 %' in text and 'effect load_torque appeared' in text
    assert 'cannot open as a rosbag2 bag' in text and '1 failures' in text
    assert text.count('class="ERROR">ERROR') >= 1


@pytest.mark.slow
def test_cli_fleet_local_cluster_and_report(tmp_path, capsys):
    _fleet(tmp_path / 'fleet', motors=1, recordings=2)
    history_dir = str(tmp_path / 'history')
    args = ['fleet', str(tmp_path / 'fleet'), '--history', history_dir, '--workers', '1',
            '--no-discover', '--window-s', '1']
    assert main(args) == 0
    out = capsys.readouterr()
    assert '2 identified: 4 windows, 0 failures' in out.out
    assert 'bags 2/2' in out.err and 'windows 4/4' in out.err
    assert main(args) == 0 and '2 already in the history' in capsys.readouterr().out
    assert main(['fleet-report', history_dir, '--out', str(tmp_path / 'report')]) == 0
    assert os.path.isfile(tmp_path / 'report' / 'motor_m000.png')
    assert main(['fleet', str(tmp_path / 'nowhere'), '--history', history_dir]) == 2


def test_a_motor_of_absurd_rows_is_flagged_and_the_others_reported(tmp_path):
    """Issue 30, item 16: Ra NaN, J -1e308 failed the whole report (arange)."""
    _synthetic_history(tmp_path / 'history')
    values = {'Ra': float('nan'), 'La': 0.016, 'CPhi': 0.7, 'J': -1e308, 'b': 0.3, 'Mc': 1.0}
    result = {'parameters': values, 'stderr': dict.fromkeys(values, 1e-3), 'method': 'refined',
              'effects': [], 'error_before': {}, 'error_after': {}, 'unexplained': False}
    write_rows(str(tmp_path / 'history'), [dict(
        result_row(result), motor_id='site/bad', source_bag=f'/bad/{k}', window_index=0,
        window_start_ns=EPOCH_NS + k * DAY_NS, window_end_ns=EPOCH_NS + k * DAY_NS + 10 ** 10,
        run_id='r2', processed_at=None) for k in range(3)], 'r2')
    page = write_fleet_report(str(tmp_path / 'history'), str(tmp_path / 'report'))
    text = open(page, encoding='utf-8').read()
    assert 'href="#site_m2"' in text and 'href="#site_bad"' in text
    assert 'absurd values, not plotted: Ra nan' in text and 'J -1e+308' in text
    assert os.path.isfile(tmp_path / 'report' / 'motor_site_m1.png')
