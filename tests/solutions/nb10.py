"""Reference and planted wrong solutions of notebook 10's exercises.

Not part of the installed package (see ``__init__``).
"""
import numpy as np

from ._base import Solution


def inverse_mse_times_time(mse, seconds):
    """1 / (MSE x time): the inverse of the error one second of work leaves (Veach 1997, 2.4.3)."""
    return 1.0 / (np.asarray(mse, dtype=np.float64) * np.asarray(seconds, dtype=np.float64))


def efficiency_per_sample(mse, seconds):
    """1 / MSE: the time forgotten, so a slow method looks as good as its error per sample."""
    return 1.0 / np.asarray(mse, dtype=np.float64)


def combine_rounds(means, spp):
    """Rounds weighted by their samples: the mean of all the samples, whatever the rounds' sizes."""
    means, spp = np.asarray(means, dtype=np.float64), np.asarray(spp, dtype=np.float64)
    return (spp[:, None] * means).sum(axis=0) / spp.sum()


def combine_rounds_unweighted(means, spp):
    """The plain mean of the round means: a short last round counts as much as a long one."""
    return np.asarray(means, dtype=np.float64).mean(axis=0)


SOLUTIONS = {
    "10.efficiency": Solution((inverse_mse_times_time,), (efficiency_per_sample,),
                              "1 / MSE: the time left out, so a slow method is not charged for it"),
    "10.rounds": Solution((combine_rounds,), (combine_rounds_unweighted,),
                          "the round means averaged without their spp: a short round weighs as much as a long one"),
}
