"""Methods from outside the package, for the tests of ``harness.evaluation.external``: importable as
``outside_methods:<function>`` (the tests directory is on the path of the tests and of their worker processes)."""

import numpy as np

from harness.engine import Estimate
from harness.evaluation.methods import declare


@declare(recognises=True, recovers=False)
def uniform(inputs, engine):
    """Every class equally likely at every frame (the answer is the first class)."""
    n, c = len(inputs.obs), len(inputs.classes)
    return Estimate(np.asarray(inputs.classes), class_posterior=np.full((n, c), 1.0 / c))


@declare(recognises=True, recovers=False)
def fails_on_kick(inputs, engine):
    """``uniform``, except on the runs of a kick, where it raises (a message of two lines)."""
    if inputs.label == "kick":
        raise ValueError("no kick here\nthe second line is not recorded")
    return uniform(inputs, engine)


@declare(recognises=True, recovers=True)
def wrong_shape(inputs, engine):
    """A posterior of one class too many: breaks the protocol."""
    n, c = len(inputs.obs), len(inputs.classes) + 1
    return Estimate(np.asarray(inputs.classes), class_posterior=np.full((n, c), 1.0 / c))


def undeclared(inputs, engine):
    return None


@declare(recognises=True, recovers=False, protocol=99)
def future(inputs, engine):
    return None


not_callable = 3
