"""
Named random streams: every child stream is keyed by a stable name, not by spawn order.

A component that needs random numbers of its own asks for a child of the stream it was
given by name (:func:`generator`, :func:`seed_sequence`). The child's
:class:`numpy.random.SeedSequence` has the parent's entropy and pool size and the
parent's spawn key followed by the name's key in :data:`STREAMS`, the one table of
names. ``Generator.spawn`` would number children by a counter in the parent (the
``n``-th call gets key ``n``), so one added draw anywhere shifted every stream spawned
after it, the example bags' bytes and the seeded tests; a named child does not depend
on what else was derived from the parent, or in which order.

The rule:

- Every stream derived from another one is a name ``'<owner>.<stream>'`` in
  :data:`STREAMS`; the owner is the kind of parent it is derived from (a triad's
  generator, a unit's seed sequence, ...).
- A new stream takes a key that no name of the same owner uses (checked when this
  module is imported: :func:`check_unique`); existing keys never change. The same
  parent and name always give the same stream, so two objects that need different
  streams need different parents or names.
- A name whose value is a ``range`` is a family indexed from 0 (one stream per axis,
  per trial); member ``i`` has key ``range[i]``.

The keys are the ones the streams had when they were spawned in order
(``rng.spawn(3)`` gave the noise of axes x, y, z keys 0, 1, 2, the thermal model's
``rng.spawn(1)`` key 3), so every seed draws what it drew before.

Examples
--------
>>> parent = np.random.default_rng(7)
>>> thermal = generator(parent, 'triad.thermal')
>>> thermal.bit_generator.seed_seq.spawn_key
(3,)
"""

import numpy as np

STREAMS = {
    # Children of a triad's generator (QfaTriad's ``rng``).
    'triad.noise': range(0, 3),  # acceleration noise of axes x, y, z (NoiseSource)
    'triad.thermal': 3,  # ThermalModel's generator
    'triad.gyro': 0x6779726F,  # GyroTriad's generator ('gyro')
    # Child of the generator given to a ThermalModel.
    'thermal.environment': 0,  # room wander and temperature-sensor noise
    # Children of a gyro triad's generator.
    'gyro.unit': 0,  # the gyro unit's draw (turn-on bias, scale factor, ...)
    'gyro.white': 1,  # angle random walk (an SFC64 bit generator)
    'gyro.flicker': 2,  # bias instability
    'gyro.walk': 3,  # rate random walk
    # Children of a unit's seed sequence: a fleet unit's ``SeedSequence([seed, index])``,
    # draw_unit's ``SeedSequence([UNIT_STREAM, seed])``.
    'unit.model': 0,  # the unit's triad
    'unit.draws': 1,  # the study's draws for the unit (season phase, aging rates)
    'unit.component_tcs': 0x746300,  # component temperature coefficients ('tc')
    # Children of the paper experiment's seed sequence: one per trial.
    'paper.trial': range(0, 2 ** 32),
}
"""Name -> spawn key under its parent (an int) or the keys of a family (a ``range``)."""


def check_unique(table):
    """
    Check that no two names of one owner share a spawn key; raise ValueError if so.

    Parameters
    ----------
    table : dict
        Name ``'<owner>.<stream>'`` -> non-negative int or non-empty ``range`` of step 1.
    """
    spans = {}
    for name, key in table.items():
        owner, dot, stream = name.partition('.')
        if not (owner and dot and stream):
            raise ValueError(f"stream name must be '<owner>.<stream>', got {name!r}")
        if isinstance(key, range):
            if key.step != 1 or len(key) == 0 or key.start < 0:
                raise ValueError(f'stream {name!r}: a family must be a non-empty range of '
                                 f'step 1 from 0 on, got {key!r}')
            span = (key.start, key.stop)
        elif isinstance(key, int) and not isinstance(key, bool) and key >= 0:
            span = (key, key + 1)
        else:
            raise ValueError(f'stream {name!r}: key must be a non-negative int or a range, '
                             f'got {key!r}')
        for other, (start, stop) in spans.get(owner, {}).items():
            if span[0] < stop and start < span[1]:
                raise ValueError(f'streams {other!r} and {name!r} share a spawn key')
        spans.setdefault(owner, {})[name] = span


def key(name, index=None):
    """
    Return the spawn key (a 1-tuple) of ``name`` (member ``index`` of a family).

    Parameters
    ----------
    name : str
        A name of :data:`STREAMS`.
    index : int, optional
        Member of a family (required for one, refused otherwise).

    Returns
    -------
    tuple of int
    """
    if name not in STREAMS:
        raise ValueError(f'name must be a stream of STREAMS, got {name!r}')
    entry = STREAMS[name]
    if isinstance(entry, range):
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) \
                or not 0 <= index < len(entry):
            raise ValueError(f'index of stream family {name!r} must be an integer in '
                             f'[0, {len(entry)}), got {index!r}')
        return (entry[int(index)],)
    if index is not None:
        raise ValueError(f'stream {name!r} is not a family: index must be None, got {index!r}')
    return (entry,)


def seed_sequence(parent, name, index=None):
    """
    Return the child seed sequence ``name`` of ``parent``.

    Parameters
    ----------
    parent : numpy.random.SeedSequence, numpy.random.Generator or int
        The parent stream (a generator's is its bit generator's seed sequence; an int
        or a sequence of ints is a seed, ``SeedSequence(parent)``).
    name : str
        A name of :data:`STREAMS`.
    index : int, optional
        Member of a family.

    Returns
    -------
    numpy.random.SeedSequence
        The parent's entropy and pool size, spawn key ``parent.spawn_key + key(name)``.
    """
    if isinstance(parent, np.random.Generator):
        parent = parent.bit_generator.seed_seq
    elif not isinstance(parent, np.random.SeedSequence):
        parent = np.random.SeedSequence(parent)
    return np.random.SeedSequence(parent.entropy, spawn_key=parent.spawn_key + key(name, index),
                                  pool_size=parent.pool_size)


def generator(parent, name, index=None):
    """
    Return a generator of the child stream ``name`` of ``parent``.

    The bit generator is the parent generator's type (as ``Generator.spawn`` gives),
    PCG64 for a seed sequence or a seed.

    Parameters
    ----------
    parent : numpy.random.Generator, numpy.random.SeedSequence or int
        The parent stream.
    name : str
        A name of :data:`STREAMS`.
    index : int, optional
        Member of a family.

    Returns
    -------
    numpy.random.Generator
    """
    bit_generator = np.random.PCG64
    if isinstance(parent, np.random.Generator):
        bit_generator = type(parent.bit_generator)
    return np.random.Generator(bit_generator(seed_sequence(parent, name, index)))


check_unique(STREAMS)
