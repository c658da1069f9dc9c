"""Learned force reconstruction (third paper): dataset, features, compiled LSTM inference, training.

Training needs PyTorch (the ``learn`` extra); inference runs in numba.
"""
