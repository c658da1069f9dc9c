"""Physics + learning: the model-based reconstruction plus an LSTM trained on its residual."""

from __future__ import annotations

from drivesense.estimate.lstm import LSTM

__all__ = ["Hybrid"]


class Hybrid(LSTM):
    """``ModelBased`` (Eq. 2 with identified axes) plus one LSTM per component on its residual.

    The networks see the NC inputs and the model's own estimate, and learn what
    the model gets wrong (micro friction at reversals, the accelerated axis,
    cogging it leaves over).  ``fit`` needs the identified axes:
    ``Hybrid().fit(runs, model_based=identified_axes)``.
    Parameters as :class:`~drivesense.estimate.lstm.LSTM`.
    """

    name = "hybrid"
    kind = "hybrid"
