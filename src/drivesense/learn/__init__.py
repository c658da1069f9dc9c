"""Learned force reconstruction (third paper): dataset, features, compiled LSTM inference, training.

Training needs PyTorch (the ``learn`` extra); inference runs in numba.  Importing
this package registers the ``lstm`` and ``hybrid`` methods with
:func:`drivesense.estimate.make`.
"""

from __future__ import annotations

from drivesense.errors import ConfigError
from drivesense.estimate.registry import is_path, register
from drivesense.learn.estimators import LSTM, Hybrid
from drivesense.learn.model import LearnedModel, TrainConfig

__all__ = ["LSTM", "Hybrid", "LearnedModel", "TrainConfig"]


def _learned_factory(cls: type[LSTM]):
    def factory(*, model=None, config: TrainConfig | None = None) -> LSTM:
        if is_path(model):
            return cls.load(model)
        if model is not None and not isinstance(model, LearnedModel):
            raise ConfigError(f"method {cls.name!r} needs a trained model folder (--model DIR), "
                              f"got {type(model).__name__}")
        return cls(model, config=config)

    factory.__doc__ = f"{cls.__name__} from ``model`` (a trained model or its folder) or untrained with ``config``."
    return factory


register(LSTM.name, _learned_factory(LSTM), drive="linear", needs="--model DIR (drivesense train lstm)",
         summary="one 3x20 LSTM per force component on the NC trace, the third paper's network plus inputs")
register(Hybrid.name, _learned_factory(Hybrid), drive="linear", needs="--model DIR (drivesense train hybrid)",
         summary="the axis model plus one LSTM per component trained on its residual")
