"""The identifier node's logic without ROS: input health, online and paper statuses, feeding."""

from types import SimpleNamespace

import numpy as np
import pytest

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.formats.batch import BATCH_LABEL, decode_batch, encode_batch
from dcmotor_id.formats.streams import SampleInbox, StreamAligner
from dcmotor_id.streaming.input_health import batch_refusal_reason, InputHealth
from dcmotor_id.streaming.monitoring import OnlineMonitor
from dcmotor_id.streaming.summary import online_text, paper_status, parameter_key_values
from dcmotor_id.streaming.windowing import Run, WindowCutter

CHANNELS = ('voltage', 'current', 'speed')


def make_health(channels=CHANNELS, rate=1000.0):
    inbox = SampleInbox(channels, 1.0 / rate)
    aligner = StreamAligner(channels, max_delay_samples=10)
    cutter = WindowCutter(channels, rate, 1.0, 0.5, min_samples=100, clock_ns=lambda: 0,
                          restart_samples=aligner.restart_samples)
    return InputHealth(channels, inbox, aligner, cutter)


def step(health):
    """Do what the node's processing timer does: align what arrived and cut it."""
    health.inbox.drain_into(health.aligner)
    health.cutter.add(*health.aligner.pop_ready())


def refusal(labels, sizes, data):
    with pytest.raises(DcMotorIdError) as caught:
        decode_batch(labels, sizes, data)
    return str(caught.value)


def test_batch_refusals_are_classified_from_the_decoder_texts():
    t = np.arange(5) * 1e-3
    data = encode_batch(t, t, t, t)
    assert batch_refusal_reason(refusal(['time,u,i,w', 'sample'], [4, 5], data)) == \
        'bad labels'
    assert batch_refusal_reason(refusal([BATCH_LABEL, 'sample'], [4, 12], data)) == \
        'wrong sizes'
    assert batch_refusal_reason(refusal([BATCH_LABEL, 'sample'], [4, 5],
                                        encode_batch(t[::-1], t, t, t))) == \
        'times not increasing'


def test_nothing_received_yet_is_the_only_problem_at_the_start():
    health = make_health()
    assert health.problems() == ['nothing received yet']
    assert health.missing() == list(CHANNELS)
    assert health.status([]) == ('WARN', 'no samples received yet')
    assert health.with_problems('refined: Ra=1') == \
        'refined: Ra=1; input so far: nothing received yet'
    assert health.not_enough_data() == (
        'not enough data: 0 aligned samples so far, a run of at least 500 samples without '
        'loss is needed; check that the drive publishes voltage, current, speed, then call '
        'again. Input so far: nothing received yet')


def test_clean_input_has_no_problems_and_says_receiving():
    health = make_health()
    t = np.arange(2000) * 1e-3
    health.inbox.put_times(t, {channel: np.ones(t.size) for channel in CHANNELS})
    step(health)
    assert health.problems() == []
    assert health.with_problems('refined: Ra=1') == 'refined: Ra=1'
    assert health.status([]) == ('OK', 'receiving')
    assert health.not_enough_data().endswith('then call again')


def test_every_kind_of_refusal_is_named_with_its_count():
    health = make_health()
    for text in ('labelled wrong', 'times do not increase at 3', 'size 12',
                 'times do not increase at 7'):
        health.refuse_batch(text)
    t = np.arange(1000) * 1e-3
    health.inbox.put_times(np.concatenate([t, [np.nan, 1e300]]),
                           {'voltage': np.ones(t.size + 2), 'current': np.ones(t.size + 2),
                            'speed': np.full(t.size + 2, np.nan)})
    health.inbox.put_block('voltage', np.array([5]), np.array([1.0]))  # a duplicate
    step(health)
    problems = health.problems()
    assert health.missing() == []  # NaN values on speed: received, then refused
    assert '1000 invalid values (NaN/inf) refused: speed 1000' in problems
    assert ('4 malformed batches refused (bad labels 1, times not increasing 2, wrong sizes '
            '1; latest: times do not increase at 7)') in problems
    assert '2 samples with NaN or absurd times dropped' in problems
    assert '1 duplicate values dropped' in problems
    assert health.malformed['times not increasing'] == 2


def test_a_missing_channel_is_named_and_warned():
    health = make_health()
    t = np.arange(100) * 1e-3
    health.inbox.put_times(t, {'voltage': t, 'current': t})
    step(health)
    assert health.missing() == ['speed']
    assert health.problems()[0] == 'nothing received on speed'
    assert health.status([]) == ('WARN', 'nothing received on speed')


def test_status_levels_in_order_of_precedence():
    health = make_health()
    t = np.arange(100) * 1e-3
    health.inbox.put_times(t, {channel: t for channel in CHANNELS})
    health.refuse_batch('size 12')
    assert health.status([]) == ('WARN', 'receiving; malformed batches refused')
    assert health.status(['current', 'speed']) == ('WARN', 'stopped: current, speed')
    assert health.status([], 'cannot record to /x') == ('ERROR', 'cannot record to /x')
    assert health.status([], None)[0] == 'WARN'


def test_stopped_channels_are_new_only_once():
    health = make_health()
    health.inbox.last_seen.update(voltage=100.0, current=100.0, speed=109.5)
    assert health.stopped(2.0, now=101.0) == ([], [])
    assert health.stopped(2.0, now=103.0) == (['current', 'voltage'], ['current', 'voltage'])
    assert health.stopped(2.0, now=104.0) == (['current', 'voltage'], [])
    assert health.stopped(2.0, now=112.0) == (['current', 'speed', 'voltage'], ['speed'])
    assert health.stalled == {'current', 'speed', 'voltage'}
    health.inbox.last_seen.update(voltage=112.0, current=112.0, speed=112.0)
    assert health.stopped(2.0, now=112.5) == ([], [])
    assert health.stopped(2.0, now=115.0)[1] == ['current', 'speed', 'voltage']


def test_key_values_keep_their_keys_and_order():
    health = make_health()
    t = np.arange(2000) * 1e-3
    health.inbox.put_times(t, {'voltage': t, 'current': t, 'speed': np.full(t.size, np.inf)})
    health.refuse_batch('labelled wrong')
    step(health)
    pairs = health.key_values(2, '/tmp/bags')
    keys = [key for key, _ in pairs]
    assert keys == ['received', 'emitted', 'lost', 'late', 'duplicates', 'reordered',
                    'invalid', 'restarts', 'unmatched_at_start', 'first_sample',
                    'next_sample', 'windows_in_memory', 'discarded_samples',
                    'missing_channels', 'malformed_batches', 'malformed_reason',
                    'malformed_joint_states', 'malformed_joint_state_reason', 'invalid_times',
                    'window_restarts', 'fit_restarts', 'problems',
                    'invalid.voltage', 'invalid.current', 'invalid.speed', 'record_dir']
    values = dict(pairs)
    assert values['invalid.speed'] == '2000' and values['invalid'] == '2000'
    assert values['malformed_batches'] == '1' and values['malformed_reason'] == 'labelled wrong'
    assert values['fit_restarts'] == '2' and values['record_dir'] == '/tmp/bags'
    assert values['missing_channels'] == ''
    assert values['problems'] == '; '.join(health.problems())
    assert 'record_dir' not in dict(health.key_values())
    assert dict(make_health().key_values())['first_sample'] == 'None'


def test_mechanical_channels_only():
    health = make_health(('current', 'speed'))
    health.inbox.put('current', 0, 1.0)
    assert health.missing() == ['speed']
    assert 'voltage' not in dict(health.key_values())['missing_channels']
    assert 'publishes current, speed,' in health.not_enough_data()


# ---------------------------------------------------------------- online and paper statuses
def estimate(converged=True, n_updates=500, status=''):
    return SimpleNamespace(converged=converged, n_updates=n_updates, status=status)


def test_online_text():
    assert online_text(estimate()) == 'converged after 500 samples'
    assert online_text(estimate(False, 20, 'window too short'), 'no baseline yet') == \
        'not converged after 20 samples (window too short)'
    assert online_text(estimate(), 'Ra +20 %', alarmed=True) == \
        'converged after 500 samples; Ra +20 %'


def test_paper_status():
    parameters = {'Ra': 1.5, 'La': 0.002}
    assert paper_status({'summary': 'x'}) is None
    assert paper_status({'paper': {'parameters': parameters}}) == (
        'OK', 'paper method on the same windows (comparison)',
        parameter_key_values(parameters))
    assert paper_status({'paper': 'diverged'}) == ('WARN', 'paper method failed: diverged', [])


class Recorder:
    """An estimator that records what it is fed."""

    def __init__(self, fail=False):
        self.calls = []
        self.fail = fail

    def update(self, voltage, current, speed):
        if self.fail:
            raise ValueError('bad samples')
        self.calls.append(('update', list(voltage), list(current), list(speed)))

    def break_continuity(self):
        self.calls.append(('break',))


def test_online_monitor_feeds_runs_and_breaks_continuity_after_a_gap():
    values = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    estimator = Recorder()
    monitor = OnlineMonitor(estimator)
    assert monitor.feed(Run(np.arange(2), values, False)) == ''
    assert monitor.feed(Run(np.arange(5, 7), values, True)) == ''
    assert estimator.calls == [('update', [1.0, 4.0], [2.0, 5.0], [3.0, 6.0]), ('break',),
                               ('update', [1.0, 4.0], [2.0, 5.0], [3.0, 6.0])]
    mechanical = Recorder()
    assert OnlineMonitor(mechanical).feed(Run(np.arange(2), values, True), False) == ''
    assert mechanical.calls == [('break',)]
    failing = OnlineMonitor(Recorder(fail=True))
    assert failing.feed(Run(np.arange(2), values, False)) == \
        'online update failed: ValueError: bad samples'
    assert failing.error.startswith('online update failed')
