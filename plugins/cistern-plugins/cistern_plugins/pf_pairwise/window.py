"""The square of positions the particle filter searches, without a guess or around one."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cistern_archive.pipeline.contracts import MatchGuess
from cistern_plugins.pf_pairwise.params import PFParams


@dataclass(frozen=True)
class SearchWindow:
    """The square of positions the filter searches: centre ``(x_m, y_m)``, half side ``half_m``, and the
    centre ``theta_rad`` of the heading correction's initial distribution."""

    x_m: float
    y_m: float
    half_m: float
    theta_rad: float = 0.0
    guided: bool = False

    @classmethod
    def initial(cls, p: PFParams) -> "SearchWindow":
        """The paper's ``L_init`` square around the reference sonar, θ around the compass difference."""
        return cls(0.0, 0.0, 0.5 * p.filter.l_init_m)

    @classmethod
    def around(cls, guess: MatchGuess) -> "SearchWindow":
        """The square ``±guess.radius_m`` around a localizer's guess, θ around its heading correction."""
        return cls(guess.dx_m, guess.dy_m, guess.radius_m, guess.dyaw_rad, guided=True)

    @classmethod
    def of(cls, guess: MatchGuess | None, p: PFParams) -> "SearchWindow":
        """The guess's window, or the ``L_init`` square without one."""
        return cls.initial(p) if guess is None else cls.around(guess)

    def offset(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Chebyshev distance of positions from the centre (the square's 'radius' at them)."""
        return np.maximum(np.abs(np.asarray(x) - self.x_m), np.abs(np.asarray(y) - self.y_m))

    def describe(self) -> str:
        """The window in words, for a reason."""
        if not self.guided:
            return f"the {2 * self.half_m:g} m search square; the true offset may lie outside it (raise l_init_m)"
        return (f"the ±{self.half_m:g} m search window around the guess ({self.x_m:.2f}, {self.y_m:.2f}); "
                "the true offset may lie outside it")
