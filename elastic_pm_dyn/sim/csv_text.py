"""A float table as CSV text, byte for byte what ``np.savetxt(fmt="%.17g")`` writes, compiled.

``%.17g`` round-trips every double; Python formats it at about 0.3 us a number, which was a
quarter of an offline ``simulate`` run (a Hexa row holds 95 numbers). Here the 17 significant
digits are the correctly rounded (half to even) value of |x| 10^p: the 53-bit mantissa times a
128-bit power of ten (exact for 0 <= p <= 55, truncated below 1 unit otherwise) gives the
integer part exactly and the fraction to within the mantissa's size, which decides the
rounding except within 2^-75 of a half: those few numbers (none in ordinary output) are
formatted by Python. Then the digits are laid out as C's and Python's ``%g`` does: fixed
notation for decimal exponents -4 .. 16, else d.ddd e+XX, trailing zeros dropped.
"""

from __future__ import annotations

import numpy as np
from numba import njit, objmode

P_MIN = -300  # decimal scalings p of 10^p: 16 - floor(log10 |x|) for every double, with margin
P_MAX = 345
CHARS_PER_NUMBER = 25  # "-1.2345678901234567e-308" and a delimiter


def _pow10_table() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """10^p = (T + d) 2^E with T in [2^127, 2^128) (hi, lo words), 0 <= d < 1, and d == 0 flags."""
    hi, lo, ex, exact = [], [], [], []
    for p in range(P_MIN, P_MAX + 1):
        if p >= 0:
            v = 10**p
            shift = v.bit_length() - 128
            t = v >> shift if shift > 0 else v << -shift
            is_exact = shift <= 0 or v % (1 << shift) == 0
            e = shift
        else:
            d = 10**-p
            s = 127 + d.bit_length()  # 2^s / d in [2^127, 2^128)
            t = (1 << s) // d
            is_exact = False
            e = -s
        hi.append(t >> 64)
        lo.append(t & (2**64 - 1))
        ex.append(e)
        exact.append(is_exact)
    return (np.array(hi, dtype=np.uint64), np.array(lo, dtype=np.uint64), np.array(ex, dtype=np.int64),
            np.array(exact, dtype=np.bool_))


T_HI, T_LO, T_EXP, T_EXACT = _pow10_table()
U32 = np.uint64(32)
NEAR = np.uint64(2**64 - 2**53)  # the low word of 2^(s-1) - 2^53
POW10_16 = np.uint64(10**16)
POW10_17 = np.uint64(10**17)
M32 = np.uint64(0xFFFFFFFF)


@njit(cache=True, inline="always")
def _mul64(a, b):
    """(hi, lo) words of the 128-bit product of two uint64."""
    a0, a1 = a & M32, a >> U32
    b0, b1 = b & M32, b >> U32
    p00, p01, p10, p11 = a0 * b0, a0 * b1, a1 * b0, a1 * b1
    mid = (p00 >> U32) + (p01 & M32) + (p10 & M32)
    return p11 + (p01 >> U32) + (p10 >> U32) + (mid >> U32), (mid << U32) | (p00 & M32)


@njit(cache=True)
def _digits(m, e, p, t_hi, t_lo, t_exp, t_exact):
    """round(m 2^e 10^p) (half to even) as uint64, or 0 where the rounding is not decided."""
    i = p - P_MIN
    h1, l1 = _mul64(m, t_lo[i])
    h2, l2 = _mul64(m, t_hi[i])
    v0 = l1
    v1 = l2 + h1
    v2 = h2 + (np.uint64(1) if v1 < l2 else np.uint64(0))
    s = -(e + t_exp[i])  # the value is (v + m d) 2^-s: s in [67, 132] for 10^15 <= it < 10^18
    ones = np.uint64(0xFFFFFFFFFFFFFFFF)
    hb = s - 1  # the bit of one half
    if hb >= 128:
        n = v2 >> np.uint64(s - 128)
        half_bit = (v2 >> np.uint64(hb - 128)) & np.uint64(1)
        mask = (np.uint64(1) << np.uint64(hb - 128)) - np.uint64(1)
        rest_zero = (v2 & mask) == 0 and v1 == 0 and v0 == 0
        near_half = (v2 & mask) == mask and v1 == ones and v0 >= NEAR
    else:
        n = (v2 << np.uint64(128 - s)) | (v1 >> np.uint64(s - 64))
        half_bit = (v1 >> np.uint64(hb - 64)) & np.uint64(1)
        mask = (np.uint64(1) << np.uint64(hb - 64)) - np.uint64(1)
        rest_zero = (v1 & mask) == 0 and v0 == 0
        near_half = (v1 & mask) == mask and v0 >= NEAR
    if t_exact[i]:
        if half_bit == 1 and (not rest_zero or (n & np.uint64(1)) == 1):
            n += np.uint64(1)
        return n
    if half_bit == 1:  # at or above a half: m d > 0 only adds
        return n + np.uint64(1)
    if near_half:  # within m d < 2^53 of a half
        return np.uint64(0)
    return n


@njit(cache=True)
def _put(buf, pos, text):
    for c in text:
        buf[pos] = ord(c)
        pos += 1
    return pos


@njit(cache=True)
def _format(x, bits, buf, pos, digits, t_hi, t_lo, t_exp, t_exact):
    """Write '%.17g' % x (its IEEE bits ``bits``) at buf[pos:] (``digits``: 17 bytes of
    scratch); returns the new position."""
    if x != x:
        return _put(buf, pos, "nan")
    if bits >> np.uint64(63):
        buf[pos] = 45  # '-'
        pos += 1
    if np.isinf(x):
        return _put(buf, pos, "inf")
    be = np.int64((bits >> np.uint64(52)) & np.uint64(0x7FF))
    m = bits & np.uint64(0xFFFFFFFFFFFFF)
    if be == 0:
        if m == 0:
            buf[pos] = 48
            return pos + 1
        e = -1074
    else:
        m |= np.uint64(1) << np.uint64(52)
        e = be - 1075
    top = be - 1023  # floor(log2 |x|)
    if be == 0:
        top = -1023
        mm = m
        while mm:
            top += 1
            mm >>= np.uint64(1)
        top -= 52
    k = np.int64(np.floor(top * 0.30102999566398120))
    d = np.uint64(0)
    for _ in range(3):
        d = _digits(m, e, 16 - k, t_hi, t_lo, t_exp, t_exact)
        if d == 0:
            break
        if d >= POW10_17:
            k += 1
        elif d < POW10_16:
            k -= 1
        else:
            break
    if d == 0 or d < POW10_16 or d >= POW10_17:  # undecided (a near tie): Python's formatting
        with objmode(text="unicode_type"):
            text = "{:.17g}".format(abs(x))  # noqa: UP032 (numba: no format spec in f-strings)
        return _put(buf, pos, text)
    hi = np.int64(d // np.uint64(100000000))  # 9 digits, then 8: 32-bit divisions by constants
    lo = np.int64(d) - hi * 100000000
    for j in range(16, 8, -1):
        q = lo // 10
        digits[j] = np.uint8(48 + lo - 10 * q)
        lo = q
    for j in range(8, -1, -1):
        q = hi // 10
        digits[j] = np.uint8(48 + hi - 10 * q)
        hi = q
    last = 16  # the last significant digit kept (%g drops trailing zeros)
    while last > 0 and digits[last] == 48:
        last -= 1
    if -4 <= k < 17:
        if k >= 0:
            for j in range(k + 1):
                buf[pos] = digits[j]
                pos += 1
            if last > k:
                buf[pos] = 46
                pos += 1
                for j in range(k + 1, last + 1):
                    buf[pos] = digits[j]
                    pos += 1
        else:
            buf[pos] = 48
            buf[pos + 1] = 46
            pos += 2
            for _ in range(-k - 1):
                buf[pos] = 48
                pos += 1
            for j in range(last + 1):
                buf[pos] = digits[j]
                pos += 1
        return pos
    buf[pos] = digits[0]
    pos += 1
    if last > 0:
        buf[pos] = 46
        pos += 1
        for j in range(1, last + 1):
            buf[pos] = digits[j]
            pos += 1
    buf[pos] = 101  # 'e'
    buf[pos + 1] = 45 if k < 0 else 43
    pos += 2
    a = -k if k < 0 else k
    if a >= 100:
        buf[pos] = 48 + a // 100
        pos += 1
    buf[pos] = 48 + (a // 10) % 10
    buf[pos + 1] = 48 + a % 10
    return pos + 2


@njit(cache=True)
def _table_bytes(table, bits, t_hi, t_lo, t_exp, t_exact):
    buf = np.empty(table.shape[0] * (table.shape[1] * CHARS_PER_NUMBER + 1), dtype=np.uint8)
    pos = 0
    digits = np.empty(17, dtype=np.uint8)
    for i in range(table.shape[0]):
        for j in range(table.shape[1]):
            if j:
                buf[pos] = 44  # ','
                pos += 1
            pos = _format(table[i, j], bits[i, j], buf, pos, digits, t_hi, t_lo, t_exp, t_exact)
        buf[pos] = 10
        pos += 1
    return buf[:pos]


def format_float(x: float) -> str:
    """'%.17g' % x, compiled (for the tests)."""
    return table_text(np.array([[x]], dtype=float)).rstrip("\n")


def table_text(table: np.ndarray) -> str:
    """The rows of ``table`` as CSV lines of '%.17g' numbers, each ending in a newline."""
    return table_bytes(table).decode("ascii")


def table_bytes(table: np.ndarray) -> bytes:
    """:func:`table_text` as ASCII bytes."""
    table = np.ascontiguousarray(table, dtype=float)
    if table.ndim != 2:
        table = table.reshape(len(table), -1)
    return _table_bytes(table, table.view(np.uint64), T_HI, T_LO, T_EXP, T_EXACT).tobytes()
