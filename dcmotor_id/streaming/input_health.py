"""
What went wrong with a node's sample input so far, in words and key-values (no ROS here).

The identifier node takes its samples through a :class:`~dcmotor_id.formats.streams.SampleInbox`,
aligns them with a :class:`~dcmotor_id.formats.streams.StreamAligner` and cuts them with a
:class:`~dcmotor_id.streaming.windowing.WindowCutter`; each of these counts its own refusals.
:class:`InputHealth` reads those counters, adds what only the node sees (malformed batches by
reason, channels that stopped), and renders them: the phrases of :meth:`InputHealth.problems`
(said in the answer of ``~/identify``), and the level, message and key-values of the
``streams`` status on ``/diagnostics`` (:meth:`InputHealth.status`,
:meth:`InputHealth.key_values`). Levels are the names of
:data:`dcmotor_id.streaming.monitoring.LEVELS`.
"""

from __future__ import annotations

from collections import Counter
import time
from typing import Optional, Sequence

from dcmotor_id.core.checks import Check, register
from dcmotor_id.formats.regrid import StampRegridder
from dcmotor_id.formats.streams import SampleInbox, StreamAligner
from dcmotor_id.streaming.windowing import WindowCutter

__all__ = ['batch_refusal_reason', 'InputHealth', 'KeyValues']

KeyValues = list[tuple[str, str]]


def batch_refusal_reason(text: str) -> str:
    """
    Classify why a batch was refused, from the text of its decoding error.

    Returns ``'bad labels'``, ``'times not increasing'`` or ``'wrong sizes'`` (anything else
    :func:`dcmotor_id.formats.batch.decode_batch` refuses).
    """
    if 'labelled' in text:
        return 'bad labels'
    if 'do not increase' in text:
        return 'times not increasing'
    return 'wrong sizes'


class InputHealth:
    """
    The input's problems and the ``streams`` status of a node, from its input stages.

    Parameters
    ----------
    channels : sequence of str
        The channels the node needs (``voltage``, ``current``, ``speed`` or a subset).
    inbox, aligner, cutter
        The node's input stages; their counters are read, never changed.
    regridder : StampRegridder, optional
        Where stamped messages are placed on the grid (joint states, Float64 topics by
        timestamp); its counters are said too.

    Attributes
    ----------
    malformed : collections.Counter
        Malformed batches refused, by reason (:func:`batch_refusal_reason`).
    last_malformed : str
        The latest refusal's text ('' before any).
    stalled : set of str
        Channels found stopped by the latest :meth:`stopped`.

    """

    def __init__(self, channels: Sequence[str], inbox: SampleInbox, aligner: StreamAligner,
                 cutter: WindowCutter, regridder: Optional[StampRegridder] = None) -> None:
        self.channels = tuple(channels)
        self.regridder = regridder
        self.inbox = inbox
        self.aligner = aligner
        self.cutter = cutter
        self.malformed: Counter[str] = Counter()
        self.last_malformed = ''
        #: joint_states messages refused (no such joint, no velocity or effort for it).
        self.malformed_joint_states = 0
        self.last_malformed_joint_state = ''
        self.stalled: set[str] = set()

    def refuse_batch(self, text: str) -> str:
        """Count a malformed batch refused with the error ``text``; return its reason."""
        reason = batch_refusal_reason(text)
        self.malformed[reason] += 1
        self.last_malformed = text
        return reason

    def refuse_joint_state(self, text: str) -> None:
        """Count a joint_states message refused with the reason ``text``."""
        self.malformed_joint_states += 1
        self.last_malformed_joint_state = text

    def missing(self) -> list[str]:
        """Return the channels never received, in channel order."""
        seen = set(self.inbox.last_seen)
        return [channel for channel in self.channels if channel not in seen]

    def problems(self) -> list[str]:
        """
        Say what went wrong with the input so far, one phrase per kind (empty when nothing).

        Channels never received, values refused as NaN/inf (per channel), malformed batches
        (by reason, with the latest refusal), samples with unusable times, duplicates, lost
        and late samples, restarts of the source, runs too short to keep.
        """
        stats = self.aligner.stats
        seen = set(self.inbox.last_seen)
        problems = []
        missing = self.missing()
        if missing and (seen or stats.invalid or self.malformed or
                        self.malformed_joint_states):
            problems.append(f'nothing received on {", ".join(missing)}')
        elif missing and not seen:
            problems.append('nothing received yet')
        invalid = self.invalid_by_channel()
        if any(invalid.values()):
            per_channel = ', '.join(f'{channel} {count}' for channel, count in
                                    invalid.items() if count)
            problems.append(f'{sum(invalid.values())} invalid values (NaN/inf) refused: '
                            f'{per_channel}')
        if self.malformed:
            reasons = ', '.join(f'{reason} {count}' for reason, count in
                                sorted(self.malformed.items()))
            problems.append(f'{sum(self.malformed.values())} malformed batches refused '
                            f'({reasons}; latest: {self.last_malformed})')
        if self.malformed_joint_states:
            problems.append(f'{self.malformed_joint_states} malformed joint_states refused '
                            f'(latest: {self.last_malformed_joint_state})')
        if self.inbox.invalid_times:
            problems.append(f'{self.inbox.invalid_times} samples with NaN or absurd times '
                            'dropped')
        for count, what in ((stats.duplicates, 'duplicate values dropped'),
                            (stats.lost, 'samples lost (a channel never delivered them)'),
                            (stats.late, 'values dropped as too late'),
                            (stats.restarts, 'restarts of the source (new time origin)'),
                            (self.cutter.discarded_samples,
                             'samples in runs too short to keep')):
            if count:
                problems.append(f'{count} {what}')
        return problems

    def invalid_by_channel(self) -> dict[str, int]:
        """Return the values refused as NaN/inf per channel (aligner and regridder)."""
        counts = dict(self.aligner.invalid_by_channel)
        if self.regridder is not None:
            for channel, count in self.regridder.invalid_by_channel.items():
                counts[channel] = counts.get(channel, 0) + count
        return counts

    def placement(self) -> list[str]:
        """Say per stamped topic how its messages were placed on the grid (or nothing)."""
        return self.regridder.summary() if self.regridder is not None else []

    def with_problems(self, summary: str) -> str:
        """
        Append the input's problems to the summary of a success (never a silent one).

        With stamped topics, how their messages were placed, resampled, lost and dropped is
        said too.
        """
        problems = self.problems()
        placement = self.placement()
        return (summary + (f'; input so far: {"; ".join(problems)}' if problems else '') +
                (f'; placed on the grid: {"; ".join(placement)}' if placement else ''))

    def not_enough_data(self) -> str:
        """Return the answer of ``~/identify`` when no window is long enough."""
        problems = self.problems()
        placement = self.placement()
        return (f'not enough data: {self.cutter.held_samples} aligned samples so far, a run '
                f'of at least {self.cutter.min_samples} samples without loss is needed; check '
                f'that the drive publishes {", ".join(self.channels)}, then call again' +
                (f'. Input so far: {"; ".join(problems)}' if problems else '') +
                (f'. Placed on the grid: {"; ".join(placement)}' if placement else ''))

    def stopped(self, timeout_s: float, now: Optional[float] = None
                ) -> tuple[list[str], list[str]]:
        """
        Find the channels received once but silent for more than ``timeout_s``.

        Returns the stopped channels and those among them that were not stopped at the
        previous call (sorted), and remembers the stopped ones in :attr:`stalled`.
        ``now`` is a :func:`time.monotonic` reading (default: now).
        """
        now = time.monotonic() if now is None else now
        seen = dict(self.inbox.last_seen)
        stopped = sorted(channel for channel in self.channels
                         if channel in seen and now - seen[channel] > timeout_s)
        newly = sorted(set(stopped) - self.stalled)
        self.stalled = set(stopped)
        return stopped, newly

    def status(self, stopped: Sequence[str], recorder_error: Optional[str] = None
               ) -> tuple[str, str]:
        """
        Return the level (``OK``, ``WARN``, ``ERROR``) and message of the ``streams`` status.

        ``stopped`` are the channels :meth:`stopped` found; a ``recorder_error`` (a full
        disk, say) overrides everything.
        """
        level, message = 'OK', 'receiving'
        missing = self.missing()
        if not self.inbox.last_seen:
            level, message = 'WARN', 'no samples received yet'
        elif stopped:
            level, message = 'WARN', f'stopped: {", ".join(stopped)}'
        elif missing:
            level, message = 'WARN', f'nothing received on {", ".join(missing)}'
        if self.malformed and level == 'OK':
            level, message = 'WARN', 'receiving; malformed batches refused'
        if self.malformed_joint_states and level == 'OK':
            level, message = 'WARN', 'receiving; malformed joint states refused'
        if recorder_error:
            level, message = 'ERROR', recorder_error
        return level, message

    def key_values(self, fit_restarts: int = 0, record_dir: Optional[str] = None) -> KeyValues:
        """
        Return the key-values of the ``streams`` status.

        The aligner's counters (:class:`~dcmotor_id.formats.streams.AlignerStats`), then
        ``first_sample``, ``next_sample``, ``windows_in_memory``, ``discarded_samples``,
        ``missing_channels``, ``malformed_batches``, ``malformed_reason``,
        ``malformed_joint_states``, ``malformed_joint_state_reason``, ``invalid_times``,
        ``window_restarts``, ``fit_restarts`` (restarts of the fit process), ``problems``,
        ``invalid.<channel>``, with stamped topics ``regrid.<topic>.<counter>``
        (:class:`~dcmotor_id.formats.regrid.SourceStats`) and, when recording,
        ``record_dir``.
        """
        pairs = [(key, str(value)) for key, value in self.aligner.stats.as_dict().items()]
        pairs += [('first_sample', str(self.aligner.first_index)),
                  ('next_sample', str(self.aligner.next_index)),
                  ('windows_in_memory', str(len(self.cutter.windows))),
                  ('discarded_samples', str(self.cutter.discarded_samples)),
                  ('missing_channels', ', '.join(self.missing())),
                  ('malformed_batches', str(sum(self.malformed.values()))),
                  ('malformed_reason', self.last_malformed),
                  ('malformed_joint_states', str(self.malformed_joint_states)),
                  ('malformed_joint_state_reason', self.last_malformed_joint_state),
                  ('invalid_times', str(self.inbox.invalid_times)),
                  ('window_restarts', str(self.cutter.restarts)),
                  ('fit_restarts', str(fit_restarts)),
                  ('problems', '; '.join(self.problems()))]
        pairs += [(f'invalid.{channel}', str(count))
                  for channel, count in self.invalid_by_channel().items()]
        if self.regridder is not None:
            pairs += self.regridder.key_values()
        if record_dir is not None:
            pairs.append(('record_dir', record_dir))
        return pairs


register(Check('batch', 'read', 'batch', batch_refusal_reason,
               "why a node's incoming batch was refused (labels, times, sizes)"))
