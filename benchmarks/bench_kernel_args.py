"""What passing a compiled kernel its inputs costs, by how they are grouped.

The same numba kernel (one rig, a few array reads) called with its 16 inputs as 16 arguments, as
three named tuples, and as three plain tuples; medians of ``--repeats`` timings of ``--calls`` calls,
in microseconds a call. Numba types a plain tuple (and an array or a scalar) from a fingerprint
computed in C; a named tuple falls back to a type lookup in Python on every call. The PID's loop
(``PID.loop()``) is a plain tuple for that reason; the per-period kernels of
:mod:`microg_env.envs.period` keep flat arguments (``docs/development.md``).

Usage: ``python benchmarks/bench_kernel_args.py [--calls 20000] [--repeats 5]``.
"""

from __future__ import annotations

import argparse
import sys
from typing import NamedTuple

import numpy as np
from numba import njit
from timing import median_seconds


class Group(NamedTuple):
    first: np.ndarray
    second: np.ndarray
    third: np.ndarray
    scale: float
    count: int


FIRST, SECOND, THIRD, SCALE, COUNT = range(5)


@njit(nogil=True)
def spread(ids, a, b, c, d, e, a2, b2, c2, d2, e2, a3, b3, c3, d3, e3):
    total = 0.0
    for j in range(ids.size):
        total += a[ids[j]] + b[ids[j]] + c[ids[j]] + d + e + a2[0] + a3[0]
    return total


@njit(nogil=True)
def named(ids, g1, g2, g3):
    total = 0.0
    for j in range(ids.size):
        total += g1.first[ids[j]] + g1.second[ids[j]] + g1.third[ids[j]] + g1.scale + g1.count
        total += g2.first[0] + g3.first[0]
    return total


@njit(nogil=True)
def positional(ids, g1, g2, g3):
    total = 0.0
    for j in range(ids.size):
        total += g1[FIRST][ids[j]] + g1[SECOND][ids[j]] + g1[THIRD][ids[j]] + g1[SCALE] + g1[COUNT]
        total += g2[FIRST][0] + g3[FIRST][0]
    return total


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    ids = np.arange(1)
    groups = [Group(np.zeros(4), np.zeros(4), np.zeros(4), 1.0, 2) for _ in range(3)]
    cases = {
        "16 arguments": (spread, (ids, *[value for group in groups for value in group])),
        "3 named tuples": (named, (ids, *groups)),
        "3 plain tuples": (positional, (ids, *[tuple(group) for group in groups])),
    }
    baseline = None
    print(f"{'inputs':<16}{'us a call':>10}{'ratio':>8}")
    for name, (kernel, inputs) in cases.items():
        kernel(*inputs)  # compiled before timing

        def calls(kernel=kernel, inputs=inputs) -> None:
            for _ in range(args.calls):
                kernel(*inputs)

        microseconds = median_seconds(calls, args.repeats) / args.calls * 1e6
        baseline = baseline or microseconds
        print(f"{name:<16}{microseconds:>10.2f}{microseconds / baseline:>8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
