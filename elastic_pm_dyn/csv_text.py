"""A float table as CSV text, byte for byte what ``np.savetxt(fmt="%.17g")`` writes, compiled.

``%.17g`` round-trips every double; Python formats it at about 0.3 us a number, which was a
quarter of an offline ``simulate`` run (a Hexa row holds 95 numbers; measured 2026-11-25 on
the 2-core dev machine). Here the 17 significant
digits are the correctly rounded (half to even) value of |x| 10^p: the 53-bit mantissa times a
128-bit power of ten (exact for 0 <= p <= 55, truncated below 1 unit otherwise) gives the
integer part exactly and the fraction to within the mantissa's size, which decides the
rounding except within 2^-75 of a half: those few numbers (none in ordinary output) are
formatted by Python. The decimal exponent k = floor(log10 |x|) comes from two tables over the
binary exponent (the largest k with 10^k <= 2^top, and the smallest double >= 10^(k+1)), so one
product gives the digits; only |x| rounding up to 10^(k+1) moves k once more. The digits
come 8 at a time as one ASCII word (SWAR), stored unaligned, and are laid out as C's and
Python's ``%g`` does: fixed notation for decimal exponents -4 .. 16, else d.ddd e+XX, trailing
zeros dropped. All in one compiled loop over the table, about 14 ns a number.
"""

from __future__ import annotations

import math
from typing import BinaryIO

import numpy as np
from llvmlite import ir
from numba import njit, objmode, types
from numba.extending import intrinsic

P_MIN = -300  # decimal scalings p of 10^p: 16 - floor(log10 |x|) for every double, with margin
P_MAX = 345
TOP_MIN = -1074  # floor(log2 |x|) of the smallest subnormal
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


def _exponent_table() -> tuple[np.ndarray, np.ndarray]:
    """Over top = floor(log2 |x|) from TOP_MIN to 1023: the largest k with 10^k <= 2^top, and the
    smallest double >= 10^(k+1) (so floor(log10 |x|) is k + (|x| >= it), exactly)."""

    tens = [10**n for n in range(326)]

    def below(a: int, b: int, n: int) -> bool:  # a / b < 10^n (exact integers)
        return a < b * tens[n] if n >= 0 else a * tens[-n] < b

    ks, thr = [], []
    for top in range(TOP_MIN, 1024):
        two = (1 << top, 1) if top >= 0 else (1, 1 << -top)
        k = math.floor(top * math.log10(2))
        while not below(*two, k + 1):
            k += 1
        while below(*two, k):
            k -= 1
        t = float(f"1e{k + 1}")  # correctly rounded; step up once if it fell below
        if below(*t.as_integer_ratio(), k + 1):
            t = math.nextafter(t, math.inf)
        ks.append(k)
        thr.append(t)
    return np.array(ks, dtype=np.int64), np.array(thr, dtype=np.float64)


# row p - P_MIN: 10^p's words hi, lo, exponent E (two's complement) and d == 0 (1 or 0)
POW10 = np.ascontiguousarray(np.stack([a.astype(np.int64).view(np.uint64) if a.dtype != np.uint64 else a
                                       for a in _pow10_table()], axis=1))
# row top - TOP_MIN: floor(log10 2^top) (two's complement) and the bits of the double >= 10 times that power
DECADE = np.ascontiguousarray(np.stack([a.view(np.uint64) for a in _exponent_table()], axis=1))
TWO_DIGITS = np.frombuffer("".join(f"{i:02d}" for i in range(100)).encode("ascii"), dtype=np.uint8).copy()
U32 = np.uint64(32)
NEAR = np.uint64(2**64 - 2**53)  # the low word of 2^(s-1) - 2^53
ABS = np.uint64(2**63 - 1)
POW10_16 = np.uint64(10**16)
POW10_17 = np.uint64(10**17)
E8 = np.uint64(10**8)
E4 = np.uint64(10**4)
E2 = np.uint64(100)
ZEROS = np.uint64(0x3030303030303030)  # "00000000"
ZERO_POINT = np.uint64(0x303030303030_2E30)  # "0.000000"
SLACK = 40  # bytes past the end that the 8-byte stores of the last number may touch
CHUNK_BYTES = 1 << 18  # write_table's buffer: stays in cache, and few write calls


@intrinsic
def _mul64(typingctx, a, b):
    """(hi, lo) words of the 128-bit product of two uint64 (one multiply instruction)."""
    if a != types.uint64 or b != types.uint64:
        return None
    sig = types.UniTuple(types.uint64, 2)(types.uint64, types.uint64)

    def codegen(context, builder, signature, args):
        wide = ir.IntType(128)
        p = builder.mul(builder.zext(args[0], wide), builder.zext(args[1], wide))
        hi = builder.trunc(builder.lshr(p, ir.Constant(wide, 64)), ir.IntType(64))
        lo = builder.trunc(p, ir.IntType(64))
        return context.make_tuple(builder, signature.return_type, (hi, lo))

    return sig, codegen


def _byte_pointer(context, builder, aryty, ary, idx):
    data = context.make_array(aryty)(context, builder, value=ary).data
    return builder.bitcast(builder.gep(data, [idx]), ir.IntType(64).as_pointer())


@intrinsic
def _put1(typingctx, ary, idx, val):
    """ary[idx] = val for a uint8 array, without the negative-index wraparound."""
    if not (isinstance(ary, types.Array) and ary.dtype == types.uint8 and isinstance(idx, types.Integer)
            and isinstance(val, types.Integer)):
        return None

    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, value=args[0]).data
        byte = ir.IntType(8)
        v = args[2] if args[2].type == byte else builder.trunc(args[2], byte)
        builder.store(v, builder.gep(data, [args[1]]))
        return context.get_dummy_value()

    return types.none(ary, idx, val), codegen


@intrinsic
def _store8(typingctx, ary, idx, val):
    """The 8 bytes of val (little-endian) at ary[idx:idx + 8] of a uint8 array, one unaligned store."""
    if not (isinstance(ary, types.Array) and ary.dtype == types.uint8 and isinstance(idx, types.Integer)
            and val == types.uint64):
        return None

    def codegen(context, builder, signature, args):
        builder.store(args[2], _byte_pointer(context, builder, signature.args[0], args[0], args[1]), align=1)
        return context.get_dummy_value()

    return types.none(ary, idx, val), codegen


@intrinsic
def _leading_zeros(typingctx, val):
    """The number of leading zero bits of a uint64 (64 for 0)."""
    if val != types.uint64:
        return None

    def codegen(context, builder, signature, args):
        return builder.ctlz(args[0], ir.Constant(ir.IntType(1), 0))

    return types.uint64(val), codegen


@njit(cache=True, inline="always")
def _eight_digits(v):
    """The 8 decimal digits of v < 10^8 as bytes 0..7 of a uint64, the first digit lowest
    (SWAR: 4 + 4 digits in 32-bit lanes, 2 + 2 in 16-bit lanes, 1 + 1 in bytes; the
    multiply-shifts are exact divisions by 100 below 10^4 and by 10 below 100)."""
    x = (v // E4) | ((v % E4) << U32)
    y = ((x * np.uint64(10486)) >> np.uint64(20)) & np.uint64(0x0000007F0000007F)
    z = y | ((x - E2 * y) << np.uint64(16))
    t = ((z * np.uint64(103)) >> np.uint64(10)) & np.uint64(0x000F000F000F000F)
    return t | ((z - np.uint64(10) * t) << np.uint64(8))


@njit(cache=True, inline="always")
def _digits(m, e, t_hi, t_lo, t_exp, t_exact):
    """round(m 2^e 10^p) (half to even) as uint64, or 0 where the rounding is not decided;
    10^p = (t_hi 2^64 + t_lo + d) 2^t_exp, d == 0 if t_exact (the tables' row of p)."""
    h1, l1 = _mul64(m, t_lo)
    h2, l2 = _mul64(m, t_hi)
    v0 = l1
    v1 = l2 + h1
    v2 = h2 + (np.uint64(1) if v1 < l2 else np.uint64(0))
    s = -(e + t_exp)  # the value is (v + m d) 2^-s: s in [67, 132] for 10^15 <= it < 10^18
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
    up = half_bit  # round up at or above a half (added, not branched on: it is a coin toss)
    if t_exact:
        if rest_zero:  # exactly a half: to even
            up &= n
    elif near_half and half_bit == 0:  # within m d < 2^53 below a half (m d > 0 only adds)
        return np.uint64(0)
    return n + up


@njit(cache=True)
def _put(buf, pos, text):
    for c in text:
        buf[pos] = ord(c)
        pos += 1
    return pos


@njit(cache=True)
def _python_format(x, buf, pos):
    """'%.17g' % |x| by Python, for the undecided near ties."""
    with objmode(text="unicode_type"):
        text = "{:.17g}".format(abs(x))  # noqa: UP032 (numba: no format spec in f-strings)
    return _put(buf, pos, text)


@njit(cache=True, inline="always")
def _subnormal_top(m):
    """floor(log2 (m 2^-1074)) for 0 < m < 2^52."""
    top = -1075
    while m:
        top += 1
        m >>= np.uint64(1)
    return top


@njit(cache=True)
def _rows_text(table, bits, start, stop, buf, pow10, decade, two):
    """Rows start..stop-1: '%.17g' of every number, ',' between, a newline after each row, at
    buf[0:] (_row_bytes(columns) a row and SLACK); returns the length. One flat loop (no array
    passed to an inlined helper: each such pass costs reference counting per number)."""
    pos = 0
    for i in range(start, stop):
        for j in range(table.shape[1]):
            if j:
                _put1(buf, pos, 44)  # ','
                pos += 1
            b = bits[i, j]
            be = np.int64((b >> np.uint64(52)) & np.uint64(0x7FF))
            m = b & np.uint64(0xFFFFFFFFFFFFF)
            if be == 0x7FF and m:
                _put1(buf, pos, 110)  # 'nan', of either sign
                _put1(buf, pos + 1, 97)
                _put1(buf, pos + 2, 110)
                pos += 3
                continue
            if b >> np.uint64(63):
                _put1(buf, pos, 45)  # '-'
                pos += 1
            if be == 0x7FF:
                _put1(buf, pos, 105)  # 'inf'
                _put1(buf, pos + 1, 110)
                _put1(buf, pos + 2, 102)
                pos += 3
                continue
            if be == 0:
                if m == 0:
                    _put1(buf, pos, 48)
                    pos += 1
                    continue
                e = -1074
                top = _subnormal_top(m)
            else:
                m |= np.uint64(1) << np.uint64(52)
                e = be - 1075
                top = be - 1023
            t = np.uint64(top - TOP_MIN)  # unsigned indices: no wraparound code
            k = np.int64(decade[t, 0])  # floor(log10 |x|): compared as bits, as doubles
            if (b & ABS) >= decade[t, 1]:
                k += 1
            r = np.uint64(16 - k - P_MIN)
            d = _digits(m, e, pow10[r, 0], pow10[r, 1], np.int64(pow10[r, 2]), pow10[r, 3])
            if d == 0:  # undecided (a near tie): Python's formatting
                pos = _python_format(table[i, j], buf, pos)
                continue
            if d == POW10_17:  # rounded up to the next power of ten
                d = POW10_16
                k += 1
            # the 17 digits: the first, then 8 + 8 as ASCII words; ``last`` the last one kept
            # (%g drops trailing zeros)
            hi = d // E8
            lo = d - hi * E8
            first = hi // E8
            u1 = _eight_digits(hi - first * E8)
            u2 = _eight_digits(lo)
            if u2:
                last = 16 - np.int64(_leading_zeros(u2) >> np.uint64(3))
            elif u1:
                last = 8 - np.int64(_leading_zeros(u1) >> np.uint64(3))
            else:
                last = 0
            c0 = np.uint8(48 + first)
            w1 = u1 + ZEROS
            w2 = u2 + ZEROS
            if -4 <= k < 17:
                if k >= 0:  # all 17 digits, then over them from digit k+1 on: '.' and those digits
                    _put1(buf, pos, c0)
                    _store8(buf, pos + 1, w1)
                    _store8(buf, pos + 9, w2)
                    if last > k:  # (then k <= 15) digits k+1.. are bytes k.. of w1 w2
                        if k < 8:
                            sh = np.uint64(8 * k)
                            f0 = (w1 >> sh) | ((w2 << (np.uint64(63) - sh)) << np.uint64(1))
                            f1 = w2 >> sh
                        else:
                            f0 = w2 >> np.uint64(8 * k - 64)
                            f1 = np.uint64(0)
                        _put1(buf, pos + k + 1, 46)
                        _store8(buf, pos + k + 2, f0)
                        _store8(buf, pos + k + 10, f1)
                        pos += last + 2
                    else:
                        pos += k + 1
                else:  # 0.000ddd
                    _store8(buf, pos, ZERO_POINT)
                    p = pos + 1 - k
                    _put1(buf, p, c0)
                    _store8(buf, p + 1, w1)
                    _store8(buf, p + 9, w2)
                    pos = p + last + 1
                continue
            _put1(buf, pos, c0)
            _put1(buf, pos + 1, 46)
            _store8(buf, pos + 2, w1)
            _store8(buf, pos + 10, w2)
            pos += last + 2 if last > 0 else 1
            _put1(buf, pos, 101)  # 'e'
            if k < 0:
                _put1(buf, pos + 1, 45)
                a = -k
            else:
                _put1(buf, pos + 1, 43)
                a = k
            pos += 2
            if a >= 100:
                _put1(buf, pos, 48 + a // 100)
                a %= 100
                pos += 1
            _put1(buf, pos, two[np.uint64(2 * a)])
            _put1(buf, pos + 1, two[np.uint64(2 * a + 1)])
            pos += 2
        _put1(buf, pos, 10)
        pos += 1
    return pos


def format_float(x: float) -> str:
    """'%.17g' % x, compiled (for the tests)."""
    return table_text(np.array([[x]], dtype=float)).rstrip("\n")


def table_text(table: np.ndarray) -> str:
    """The rows of ``table`` as CSV lines of '%.17g' numbers, each ending in a newline."""
    return table_bytes(table).decode("ascii")


def table_bytes(table: np.ndarray) -> bytes:
    """:func:`table_text` as ASCII bytes."""
    table = _as_table(table)
    buf = np.empty(len(table) * _row_bytes(table.shape[1]) + SLACK, dtype=np.uint8)
    n = _rows_text(table, table.view(np.uint64), 0, len(table), buf, POW10, DECADE, TWO_DIGITS)
    return buf[:n].tobytes()


def write_table(f: BinaryIO, table: np.ndarray) -> None:
    """Write :func:`table_bytes` to the binary file ``f``, formatted CHUNK_BYTES at a time into
    one reused buffer (cache-warm, no page faults of a whole-table buffer, no copies)."""
    table = _as_table(table)
    bits = table.view(np.uint64)
    rows = max(1, CHUNK_BYTES // _row_bytes(table.shape[1]))
    buf = np.empty(min(rows, len(table)) * _row_bytes(table.shape[1]) + SLACK, dtype=np.uint8)
    for start in range(0, len(table), rows):
        n = _rows_text(table, bits, start, min(start + rows, len(table)), buf, POW10, DECADE, TWO_DIGITS)
        f.write(buf[:n])


def _as_table(table: np.ndarray) -> np.ndarray:
    table = np.ascontiguousarray(table, dtype=float)
    return table if table.ndim == 2 else table.reshape(len(table), -1)


def _row_bytes(columns: int) -> int:
    return columns * CHARS_PER_NUMBER + 1
