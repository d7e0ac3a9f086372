"""Elementary functions in a form that vectorises inside numba loops.

libm's ``exp``, ``log`` and ``atan`` are opaque calls to LLVM, so a loop that calls them runs one element at a
time; written as range reductions and polynomials, the same loops run on vector registers. All agree with numpy
to a few units in the last place (``tests/test_engine_parts.py``).

``FAST`` is the kernels' fastmath set: sums may be reordered and multiply-adds fused; nothing assumes away NaN
or infinity. Kernels that divide inside loops also take ``error_model="numpy"`` (no zero-division branch).

numba checks only a kernel's own file before it reuses the kernel's cache, and the kernels of other modules
inline these functions: the package therefore keeps its kernels in a cache directory per version of every file
that compiles kernels (``harness.kernel_cache_dir``), so that an edit here recompiles them.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types
from numba.extending import intrinsic

FAST = {"reassoc", "contract", "arcp", "nsz"}
EXP_MIN = -708.0                          # below this, exp is not a normal double: taken as zero
_LN2_HI = 6.93147180369123816490e-01      # ln 2 split in two for an exact range reduction (Cody and Waite)
_LN2_LO = 1.90821492927058770002e-10
_INV_LN2 = 1.44269504088896338700e+00
_TAN_PI_8 = 0.41421356237309503           # sqrt(2) - 1


# 1.5 * 2^52: for an integral double k with |k| < 2^51, the bits of k + _ROUNDING are those of _ROUNDING plus k.
_ROUNDING = 6755399441055744.0


def _reinterpretation(source, target):
    """A numba intrinsic that reads the bits of a ``source`` number as a ``target`` number of the same width (a
    reinterpretation: no instruction, unlike a conversion)."""
    def reinterpret(typingctx, x):
        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(target))
        return target(source), codegen
    return intrinsic(reinterpret)


_bits = _reinterpretation(types.float64, types.int64)        # a double's bit pattern
_double = _reinterpretation(types.int64, types.float64)      # the double of a bit pattern
_bits32 = _reinterpretation(types.float32, types.int32)
_single = _reinterpretation(types.int32, types.float32)


@numba.njit(inline="always", fastmath=FAST)
def exp_parts(x):
    """``exp(x) = m * s`` for ``x`` in ``[EXP_MIN, 709]``: ``s = 2^k`` (``k = round(x / ln 2)``) and ``m = exp(r)``
    (``|r| <= ln(2) / 2``) by its Taylor polynomial of degree 13, truncation below 1e-17. Inlined, so that the
    caller's loop vectorises and may fuse its own arithmetic with it.

    The polynomial is evaluated by Estrin's scheme (pairs of terms joined by ``r^2``, ``r^4`` and ``r^8``): its
    longest chain of dependent multiply-adds is 5 against Horner's 13, and the density loops, which have little
    else to overlap with that chain, were bound by its latency (17% of the density loop's time on an AMD Zen 3).

    ``2^k`` is built from its bits, ``(k + 1023) << 52``, with ``k``'s integer taken from the bits of ``k + 1.5 *
    2^52`` rather than by a conversion: CPUs without AVX-512 have no vector instruction that converts doubles
    to 64-bit integers, and the conversion, done one element at a time, cost the density loop 5% of its time
    on an AMD Zen 3 (docs/log/2026-12-06-speed-step-11.md)."""
    k = np.floor(x * _INV_LN2 + 0.5)
    r = (x - k * _LN2_HI) - k * _LN2_LO
    r2 = r * r
    r4 = r2 * r2
    low = (1.0 + r + r2 * (1 / 2 + r * (1 / 6))) + r4 * ((1 / 24 + r * (1 / 120)) + r2 * (1 / 720 + r * (1 / 5040)))
    high = ((1 / 40320 + r * (1 / 362880)) + r2 * (1 / 3628800 + r * (1 / 39916800))) + r4 * (
        1 / 479001600 + r * (1 / 6227020800))
    return low + (r4 * r4) * high, _double((_bits(k + _ROUNDING) + 1023) << 52)


# float32 constants: numba types a Python float literal as a double, which would widen a float32 loop.
_F = np.float32
EXP32_MIN = _F(-86.0)                     # below this, exp32_parts' power of two would not be a normal float32
_LN2_HI32 = _F(0.693359375)               # 8 significant bits: k * _LN2_HI32 is exact for |k| < 2^16
_LN2_LO32 = _F(-2.12194440e-4)
_INV_LN2_32 = _F(1.4426950408889634)
_ROUNDING32 = _F(12582912.0)              # 1.5 * 2^23: the float32 analogue of _ROUNDING
_E = [_F(1.0 / np.prod(np.arange(1, k + 1, dtype=float))) for k in range(8)]
_E0, _E1, _E2, _E3, _E4, _E5, _E6, _E7 = _E
_HALF32 = _F(0.5)


@numba.njit(inline="always", fastmath=FAST)
def exp32_parts(x):
    """``exp_parts`` in float32, for ``x`` (float32) in ``[EXP32_MIN, 88]``: ``exp(x) = m * 2^k`` with ``m`` by
    the Taylor polynomial of degree 7 (truncation below 3e-9 for ``|r| <= ln(2) / 2``, under float32's unit
    round-off 6e-8; Estrin's scheme) and ``2^k`` from the bits of ``k + 1.5 * 2^23``. A float32 vector holds twice
    the lanes of a double one."""
    k = np.floor(x * _INV_LN2_32 + _HALF32)
    r = (x - k * _LN2_HI32) - k * _LN2_LO32
    r2 = r * r
    p = (_E0 + r * _E1) + r2 * (_E2 + r * _E3) + (r2 * r2) * ((_E4 + r * _E5) + r2 * (_E6 + r * _E7))
    return p, _single((_bits32(k + _ROUNDING32) + np.int32(127)) << np.int32(23))


@numba.njit(cache=True, fastmath=FAST)
def exp_into(x, out, scale):
    """``out[i] = exp(x[i])`` (zero below ``EXP_MIN``, arguments above 709 clipped; ``exp_parts``). ``scale``:
    work array of the same length."""
    n = len(x)
    for i in range(n):
        out[i], scale[i] = exp_parts(min(max(x[i], EXP_MIN), 709.0))
    for i in range(n):
        out[i] = out[i] * scale[i] if x[i] >= EXP_MIN else 0.0


_SQRT2 = 1.4142135623730951
_MANTISSA = 0x000FFFFFFFFFFFFF
_ONE_BITS = 0x3FF0000000000000
LOG_MIN = 2.2250738585072014e-308          # the smallest normal double: ``log_normal`` takes these and above


@numba.njit(inline="always", fastmath=FAST)
def log_normal(x):
    """``log(x)`` for a normal double ``x`` (``x >= LOG_MIN``, finite): ``x = m 2^e`` with ``m`` in
    ``[sqrt(1/2), sqrt(2))`` from the bits (no conversion to or from integers, which AVX2 lacks in vectors),
    ``log(m) = 2 atanh(s)``, ``s = (m - 1) / (m + 1)``, by its series to ``s^23`` (``|s| <= 0.172``: truncation
    below 1e-18; Estrin's scheme). Inlined, so that the caller's loop vectorises."""
    bits = _bits(x)
    m = _double((bits & _MANTISSA) | _ONE_BITS)                 # [1, 2)
    e = _double(_bits(_ROUNDING) + ((bits >> 52) - 1023)) - _ROUNDING
    big = m >= _SQRT2
    m = 0.5 * m if big else m
    e = e + 1.0 if big else e
    s = (m - 1.0) / (m + 1.0)
    z = s * s
    z2 = z * z
    z4 = z2 * z2
    z8 = z4 * z4
    series = (((1.0 + z * (1 / 3)) + z2 * (1 / 5 + z * (1 / 7))) + z4 * ((1 / 9 + z * (1 / 11)) + z2 * (
        1 / 13 + z * (1 / 15)))) + z8 * (((1 / 17 + z * (1 / 19)) + z2 * (1 / 21 + z * (1 / 23))))
    return e * _LN2_HI + (e * _LN2_LO + 2.0 * s * series)


# atan(y) / y = sum_k (-1)^k y^(2k) / (2k + 1): 22 terms leave less than 1e-17 for |y| <= tan(pi/8).
_ATAN_SERIES = np.array([(-1) ** k / (2 * k + 1) for k in range(22)])


@numba.njit(inline="always", fastmath=FAST)
def _atan_series(y2):
    """``atan(y) / y`` from ``y^2`` (Horner)."""
    acc = 0.0
    for k in range(len(_ATAN_SERIES) - 1, -1, -1):
        acc = acc * y2 + _ATAN_SERIES[k]
    return acc


@numba.njit(inline="always", fastmath=FAST, error_model="numpy")
def atan_ratio(t):
    """``atan(t) / t`` for ``t`` in ``[0, 1]`` (1 at 0, no division by ``t`` near it). Above ``tan(pi/8)``,
    ``atan(t) = pi/4 + atan((t - 1) / (t + 1))`` brings the series' argument back below it."""
    y = (t - 1.0) / (t + 1.0)
    small = _atan_series(t * t)
    big = (np.pi / 4 + y * _atan_series(y * y)) / max(t, _TAN_PI_8)
    return small if t <= _TAN_PI_8 else big
