"""
What the loop works with: a structure of effects, its fit on the training parts, the candidates.

:class:`Structure` (the effects and their inner parameters), :class:`Fit` (a structure fitted on
the training parts and simulated over the whole records), :class:`Candidate` (one effect tried
in a search round) and :class:`Round` (a search round); the small helpers on effect terms and
record parts.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.identification.error_model.residuals import channel_errors, ChannelErrors

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.effects import Effect
    from dcmotor_id.identification.estimators.base import Estimate, ExogenousTerm


class Structure:
    """An ordered list of effects with their inner parameters: ``[(effect class, inner)]``."""

    def __init__(self, items: Sequence[tuple[type[Effect], dict]] = ()) -> None:
        self.items = list(items)

    def __len__(self) -> int:
        """Return the number of effects."""
        return len(self.items)

    def names(self) -> list[str]:
        """Vocabulary names in the order added."""
        return [cls.name for cls, _ in self.items]

    def plus(self, cls: type[Effect], inner: dict) -> Structure:
        """Return a new structure with one more effect."""
        return Structure(self.items + [(cls, dict(inner))])

    def transformed(self, records: Sequence[Record]) -> list[Record]:
        """Apply the data effects (sensor delays) to the records."""
        out = list(records)
        for cls, inner in self.items:
            if cls.TRANSFORM:
                out = cls.transform(out, inner)
        return out

    def terms(self, records: Sequence[Record], base: dict, torque_constant: float | None = None,
              initial: dict | None = None) -> tuple[ExogenousTerm, ...]:
        """All exogenous terms of the structure on (transformed) records."""
        terms: list[ExogenousTerm] = []
        for cls, inner in self.items:
            terms.extend(cls.terms(records, inner, base, torque_constant, initial))
        return tuple(terms)

    def effects(self, values: dict) -> list[Effect]:
        """Return the fitted effect instances for a parameter dict."""
        return [cls.from_fit(values, inner) for cls, inner in self.items]


def slice_terms(terms: Sequence[ExogenousTerm], stops: Sequence[int]) -> tuple[ExogenousTerm, ...]:
    """Return the terms cut to the training parts (each record's regressor up to its stop)."""
    return tuple(replace(term, regressors=tuple(reg[:stop] for reg, stop in
                                                zip(term.regressors, stops)))
                 for term in terms)


def with_initial(terms: Sequence[ExogenousTerm], values: dict) -> tuple[ExogenousTerm, ...]:
    """Return the terms with their start values taken from ``values`` where it has them."""
    return tuple(replace(term, initial=float(values.get(term.name, term.initial)))
                 for term in terms)


def join_part(arrays: Sequence[np.ndarray], stops: Sequence[int], part: str) -> np.ndarray:
    """
    Concatenate the training (``train``) or held-out (``heldout``) part of per-record arrays.

    A single record's part is a view (no copy): callers only read it.
    """
    pieces = [values[:stop] if part == 'train' else values[stop:]
              for values, stop in zip(arrays, stops)]
    return pieces[0] if len(pieces) == 1 else np.concatenate(pieces)


@dataclass
class Fit:
    """A structure fitted on the training parts and simulated over the whole records."""

    structure: Structure
    estimate: Estimate
    records: list
    stops: list
    simulated: list
    terms: tuple
    train_cost: float = 0.0
    heldout_cost: float = 0.0
    n_train: int = 0
    info: dict = field(default_factory=dict)

    @property
    def values(self) -> dict:
        """Fitted parameters (base and term coefficients)."""
        return self.estimate.parameters

    def channel_simulated(self, channel: str, part: str) -> np.ndarray:
        """Return the simulation of one channel on a part (train or heldout), concatenated."""
        return join_part([sim[channel] for sim in self.simulated], self.stops, part)

    def channel_measured(self, channel: str, part: str) -> np.ndarray:
        """Measurement of one channel on a part, concatenated."""
        return join_part([getattr(rec, channel) for rec in self.records], self.stops, part)

    def channel_residual(self, channel: str, part: str) -> np.ndarray:
        """Model minus measurement of one channel on a part, concatenated."""
        pieces = [(sim[channel][:stop] - getattr(rec, channel)[:stop]) if part == 'train' else
                  (sim[channel][stop:] - getattr(rec, channel)[stop:])
                  for rec, sim, stop in zip(self.records, self.simulated, self.stops)]
        return pieces[0] if len(pieces) == 1 else np.concatenate(pieces)

    def errors(self, outputs: Sequence[str], part: str = 'heldout') -> ChannelErrors:
        """
        ``{current_nrmse_pct, speed_nrmse_pct}`` on a part (current None if no output).

        In percent of each channel's spread over the *whole* records joined: a held-out part
        in a steady tail has a tiny spread of its own, which would make any error look huge.
        """
        errors = channel_errors({channel: self.channel_simulated(channel, part)
                                 for channel in outputs},
                                {channel: self.channel_measured(channel, part)
                                 for channel in outputs}, outputs)
        for channel in outputs:
            key = f'{channel}_nrmse_pct'
            own = float(np.std(self.channel_measured(channel, part)))
            whole = float(np.std(np.concatenate([getattr(rec, channel)
                                                 for rec in self.records])))
            value = errors.get(key)
            if value is not None and whole > 0:
                errors[key] = value * own / whole
        return errors


@dataclass(frozen=True, eq=False)
class Candidate:
    """
    One effect tried in a search round: its screen, then (maybe) its refit and score.

    Attributes
    ----------
    effect : type
        The effect class (of the vocabulary).
    inner : dict
        Its inner parameters (from the screen's grid; after a refit, the refitted ones).
    start : dict
        Start values of its coefficients (from the linearised screen).
    screen_explained : float
        Share of the residual's sum of squares the linearised screen explains.
    fit : Fit or None
        The structure with the candidate refitted on the training parts (None: not refitted,
        or the refit failed).
    problem : str or None
        Why the refitted candidate is not admissible (physics, collapse), or None.
    gain : float or None
        Relative drop of the held-out cost against the current structure.
    bic_delta : float or None
        Change of the training BIC.
    insample_gain : float or None
        Relative drop of the training cost (the part the candidate was fitted on).
    gain_noise : float or None
        Noise of ``gain``: :data:`GAIN_NOISE_FACTOR` standard errors of the drop, from its
        spread over :data:`HELDOUT_BLOCKS` contiguous blocks of the held-out part
        (:func:`heldout_gain_noise`); the gain must exceed it.

    """

    effect: type[Effect]
    inner: dict
    start: dict
    screen_explained: float
    fit: Fit | None = None
    problem: str | None = None
    gain: float | None = None
    bic_delta: float | None = None
    insample_gain: float | None = None
    gain_noise: float | None = None

    @property
    def name(self) -> str:
        """Vocabulary name of the effect."""
        return self.effect.name

    @property
    def fitted(self) -> Fit:
        """Return the refit (of a candidate that was refitted: :attr:`fit` is set)."""
        if self.fit is None:
            raise ValueError(f'{self.name} was not refitted')
        return self.fit

    def describe(self) -> dict:
        """Return the refitted effect's ``{"name", "parameters"}``."""
        values = self.fitted.values
        return self.fitted.structure.effects(values)[-1].describe(values)


@dataclass
class Round:
    """One search round: the candidates scored, the one chosen and its JSON report."""

    candidates: list[Candidate]
    chosen: Candidate | None
    report: dict
