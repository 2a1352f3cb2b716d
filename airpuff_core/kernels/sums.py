"""Sums in compiled kernels that give numpy's ``np.sum`` of a float64 array bit for bit.

numpy adds a contiguous float64 array by pairwise summation (``pairwise_sum`` of its
``loops_utils.h``): fewer than 8 values in order from 0.0; up to 128 values in 8 interleaved
partial sums, combined as ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)), then the values
left over in order; longer blocks split in two halves (the first a multiple of 8 long) summed
so.  A kernel that replaces a numpy expression ending in ``np.sum`` adds its terms this way, so
the run's results stay the same to the last bit (``tests/core/test_sums.py`` compares them).
"""

import numpy as np
from numba import njit

PAIRWISE_BLOCK = 128  # numpy's PW_BLOCKSIZE


@njit(cache=True)
def block_sum(values, start, count):
    """numpy's sum of a block of at most PAIRWISE_BLOCK values ``values[start:start + count]``."""
    if count < 8:
        total = 0.0
        for i in range(start, start + count):
            total += values[i]
        return total
    r0, r1, r2, r3 = values[start], values[start + 1], values[start + 2], values[start + 3]
    r4, r5, r6, r7 = values[start + 4], values[start + 5], values[start + 6], values[start + 7]
    whole = count - count % 8
    i = start + 8
    while i < start + whole:
        r0 += values[i]
        r1 += values[i + 1]
        r2 += values[i + 2]
        r3 += values[i + 3]
        r4 += values[i + 4]
        r5 += values[i + 5]
        r6 += values[i + 6]
        r7 += values[i + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < start + count:
        total += values[i]
        i += 1
    return total


@njit(cache=True)
def _first_half(count):
    """The length of the first half of a block split in two (a multiple of 8)."""
    half = count // 2
    return half - half % 8


@njit(cache=True)
def pairwise_sum(values, start, count):
    """numpy's sum of ``values[start:start + count]`` (module docstring).  numpy recurses into
    the halves; here an explicit stack of the halves does (Numba's cache does not keep a
    recursive function safely)."""
    if count <= PAIRWISE_BLOCK:
        return block_sum(values, start, count)
    starts = np.empty(64, np.int64)  # the blocks being summed, outermost first
    counts = np.empty(64, np.int64)
    left_done = np.zeros(64, np.bool_)  # whether the block's first half is summed
    left_sums = np.empty(64)
    top = 0
    starts[0] = start
    counts[0] = count
    while True:
        if counts[top] > PAIRWISE_BLOCK:  # descend into the first half
            starts[top + 1] = starts[top]
            counts[top + 1] = _first_half(counts[top])
            left_done[top + 1] = False
            top += 1
            continue
        value = block_sum(values, starts[top], counts[top])
        top -= 1
        while top >= 0 and left_done[top]:  # second halves finished: add them to the first
            value = left_sums[top] + value
            top -= 1
        if top < 0:
            return value
        left_sums[top] = value  # a first half finished: sum the second next
        left_done[top] = True
        half = _first_half(counts[top])
        starts[top + 1] = starts[top] + half
        counts[top + 1] = counts[top] - half
        left_done[top + 1] = False
        top += 1


@njit(cache=True)
def numpy_sum(values):
    """numpy's ``np.sum`` of the 1-D float64 array ``values``, bit for bit."""
    return pairwise_sum(values, 0, values.shape[0])
