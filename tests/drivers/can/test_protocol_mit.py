"""MIT codec: bit packing and truncating quantisation against frames worked out by hand; the fast path against it."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.can.protocol import FrameError
from drivers.can.protocol.mit import (
    CLEAR_ERROR,
    DISABLE,
    ENABLE,
    FIELD_STEPS,
    POSITION_STEPS,
    SET_ZERO,
    MitCommand,
    MitRanges,
    command_encoder,
    decode_command,
    decode_state,
    encode_command,
    encode_state,
    float_to_uint,
    quantize,
    special_kind,
    state_scales,
    uint_to_float,
)

DM4310 = MitRanges(12.5, 30.0, 10.0)
MYACTUATOR = MitRanges(12.5, 45.0, 24.0)


def test_zero_is_not_representable_and_truncates_down() -> None:
    # (0 + 12.5) * 65535 / 25 = 32767.5 -> truncated to 32767 (rounding would give 32768)
    assert float_to_uint(0.0, -12.5, 12.5, 16) == 32767
    # 32767 * 25 / 65535 - 12.5 = -0.000190737...
    assert quantize(0.0, -12.5, 12.5, 16) == pytest.approx(-0.000190737, abs=1e-9)
    # velocity over ±30, 12 bit: (30) * 4095 / 60 = 2047.5 -> 2047 -> 2047 * 60 / 4095 - 30 = -0.007326
    assert quantize(0.0, -30.0, 30.0, 12) == pytest.approx(-0.0073260, abs=1e-7)
    # truncation, not rounding: 0.99 LSB above a code still maps to that code
    lsb = 25 / 65535
    assert float_to_uint(-12.5 + 10.99 * lsb, -12.5, 12.5, 16) == 10


def test_clamping_at_range_ends() -> None:
    assert float_to_uint(100.0, -12.5, 12.5, 16) == 0xFFFF
    assert float_to_uint(-100.0, -12.5, 12.5, 16) == 0
    assert float_to_uint(math.inf, -12.5, 12.5, 16) == 0xFFFF
    assert float_to_uint(-math.inf, 0.0, 500.0, 12) == 0
    assert uint_to_float(0xFFFF, -12.5, 12.5, 16) == 12.5
    assert uint_to_float(0, -12.5, 12.5, 16) == -12.5
    with pytest.raises(ValueError, match="NaN"):
        float_to_uint(math.nan, -1.0, 1.0, 12)


def test_command_packing_by_hand() -> None:
    # DM4310 ranges p ±12.5, v ±30, t ±10, kp 0..500, kd 0..5
    # p  =  1.0 : (13.5)  * 65535 / 25  = 35388.9  -> 35388 = 0x8A3C (decodes to 35388 * 25 / 65535 - 12.5 = 0.99966)
    # v  = -2.0 : (28)    * 4095  / 60  = 1911.0   -> 1911  = 0x777
    # kp = 50   : 50      * 4095  / 500 = 409.5    -> 409   = 0x199
    # kd = 1.0  : 1       * 4095  / 5   = 819.0    -> 819   = 0x333
    # t  = 0.5  : (10.5)  * 4095  / 20  = 2149.875 -> 2149  = 0x865
    # bytes: 8A 3C | 77 | 7<<4|1 | 99 | 33 | 3<<4|8 | 65
    frame = encode_command(1.0, -2.0, 50.0, 1.0, 0.5, DM4310)
    assert frame == bytes([0x8A, 0x3C, 0x77, 0x71, 0x99, 0x33, 0x38, 0x65])
    cmd = decode_command(frame, DM4310)
    assert cmd == MitCommand(
        35388 * 25 / 65535 - 12.5, 1911 * 60 / 4095 - 30, 409 * 500 / 4095, 819 * 5 / 4095, 2149 * 20 / 4095 - 10
    )
    assert cmd.p == pytest.approx(0.99966, abs=1e-5)
    assert cmd.kp == pytest.approx(49.9389, abs=1e-4)


def test_vendor_example_frame_decodes() -> None:
    # MyActuator V4.3 example 0x401: E6 66 82 E0 52 33 3B 55 (p ±12.5, v ±45, t ±24)
    # p  = 0xE666 = 58982 -> 58982 * 25 / 65535 - 12.5 = 10.00019
    # v  = 0x82E  = 2094  -> 2094 * 90 / 4095 - 45    = 1.02198
    # kp = 0x052  = 82    -> 82 * 500 / 4095          = 10.01221
    # kd = 0x333  = 819   -> 819 * 5 / 4095           = 1.0
    # t  = 0xB55  = 2901  -> 2901 * 48 / 4095 - 24    = 10.00440
    cmd = decode_command(bytes.fromhex("E66682E052333B55"), MYACTUATOR)
    assert cmd.p == pytest.approx(10.00019, abs=1e-5)
    assert cmd.v == pytest.approx(1.02198, abs=1e-5)
    assert cmd.kp == pytest.approx(10.01221, abs=1e-5)
    assert cmd.kd == 1.0
    assert cmd.t == pytest.approx(10.00440, abs=1e-5)


def test_command_fields_clamp() -> None:
    frame = encode_command(99.0, -99.0, 1e6, -1.0, 1e3, DM4310)
    # p -> 0xFFFF, v -> 0x000, kp -> 0xFFF, kd -> 0x000, t -> 0xFFF
    assert frame == bytes([0xFF, 0xFF, 0x00, 0x0F, 0xFF, 0x00, 0x0F, 0xFF])
    assert decode_command(frame, DM4310) == MitCommand(12.5, -30.0, 500.0, 0.0, 10.0)


def test_state_block_by_hand() -> None:
    # p = 0 -> 0x7FFF, v = 0 -> 0x7FF, t = 0 -> 0x7FF  =>  7F FF | 7F | F7 | FF
    assert encode_state(0.0, 0.0, 0.0, DM4310) == bytes([0x7F, 0xFF, 0x7F, 0xF7, 0xFF])
    p, v, t = decode_state(bytes([0x7F, 0xFF, 0x7F, 0xF7, 0xFF]), DM4310)
    assert (p, v, t) == pytest.approx((-0.000190737, -0.0073260, -0.0024420), abs=1e-7)


def test_wrong_lengths_raise_frame_error() -> None:
    with pytest.raises(FrameError, match="8 data bytes, got 7"):
        decode_command(bytes(7), DM4310)
    with pytest.raises(FrameError, match="5 bytes, got 6"):
        decode_state(bytes(6), DM4310)


def test_special_frames() -> None:
    assert bytes.fromhex("FFFFFFFFFFFFFFFC") == ENABLE
    assert bytes.fromhex("FFFFFFFFFFFFFFFD") == DISABLE
    assert bytes.fromhex("FFFFFFFFFFFFFFFE") == SET_ZERO
    assert bytes.fromhex("FFFFFFFFFFFFFFFB") == CLEAR_ERROR
    assert [special_kind(f) for f in (ENABLE, DISABLE, SET_ZERO, CLEAR_ERROR)] == ["enable", "disable", "zero", "clear"]
    assert special_kind(bytes.fromhex("FFFFFFFFFFFFFFFF")) is None
    assert special_kind(ENABLE[:7]) is None


def test_ranges_reject_nonsense() -> None:
    with pytest.raises(ValueError, match="p_max"):
        MitRanges(0.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="kd_max"):
        MitRanges(1.0, 1.0, 1.0, kd_max=math.nan)


finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6)


@given(x=finite)
def test_quantize_stays_within_one_lsb_below(x: float) -> None:
    u = float_to_uint(x, -12.5, 12.5, 16)
    q = quantize(x, -12.5, 12.5, 16)
    # re-encoding a decoded value lands on the same code, or one below when float error undercuts the boundary
    assert float_to_uint(q, -12.5, 12.5, 16) in (u - 1, u)
    clamped = min(max(x, -12.5), 12.5)
    assert clamped - 25 / 65535 - 1e-12 <= q <= clamped + 1e-12  # truncation only ever rounds down


@given(p=finite, v=finite, kp=finite, kd=finite, t=finite)
def test_command_round_trip_within_one_lsb(p: float, v: float, kp: float, kd: float, t: float) -> None:
    cmd = decode_command(encode_command(p, v, kp, kd, t, DM4310), DM4310)
    for got, want, lo, hi, bits in (
        (cmd.p, p, -12.5, 12.5, 16),
        (cmd.v, v, -30.0, 30.0, 12),
        (cmd.kp, kp, 0.0, 500.0, 12),
        (cmd.kd, kd, 0.0, 5.0, 12),
        (cmd.t, t, -10.0, 10.0, 12),
    ):
        clamped = min(max(want, lo), hi)
        assert clamped - (hi - lo) / ((1 << bits) - 1) - 1e-9 <= got <= clamped + 1e-9


# ---- the host's specialised encoder: bit-identical to encode_command -------------------------------------------

ranges = st.builds(
    MitRanges,
    p_max=st.floats(1e-3, 1e4),
    v_max=st.floats(1e-3, 1e4),
    t_max=st.floats(1e-3, 1e4),
    kp_max=st.floats(1e-3, 1e4),
    kd_max=st.floats(1e-3, 1e4),
)


@st.composite
def field_value(draw: st.DrawFn, hi: float, signed: bool, bits: int) -> float:
    """Anywhere on the float line (±inf included), around the range, or exactly on a code's boundary."""
    lo = -hi if signed else 0.0
    kind = draw(st.sampled_from(["any", "near", "code", "edge"]))
    if kind == "any":
        return draw(st.floats(allow_nan=False))
    if kind == "near":
        return draw(st.floats(-2.0 * hi, 2.0 * hi))
    if kind == "code":  # a decoded value re-encoded: where truncation is most sensitive to the operation order
        return uint_to_float(draw(st.integers(0, (1 << bits) - 1)), lo, hi, bits)
    return draw(st.sampled_from([lo, hi, -0.0, 0.0, math.nextafter(hi, math.inf), math.nextafter(lo, -math.inf)]))


@st.composite
def command_case(draw: st.DrawFn) -> tuple[MitRanges, tuple[float, float, float, float, float]]:
    r = draw(ranges)
    return r, (
        draw(field_value(r.p_max, True, 16)),
        draw(field_value(r.v_max, True, 12)),
        draw(field_value(r.kp_max, False, 12)),
        draw(field_value(r.kd_max, False, 12)),
        draw(field_value(r.t_max, True, 12)),
    )


@given(case=command_case())
@settings(max_examples=400)
def test_command_encoder_writes_the_bytes_of_encode_command(
    case: tuple[MitRanges, tuple[float, float, float, float, float]],
) -> None:
    r, fields = case
    buffer = bytearray(b"\xaa" * 8)  # stale bytes from an earlier cycle must all be overwritten
    command_encoder(r)(buffer, *fields)
    assert bytes(buffer) == encode_command(*fields, r)


@given(case=command_case(), nan_at=st.integers(0, 4))
def test_command_encoder_refuses_nan_in_any_field_like_encode_command(
    case: tuple[MitRanges, tuple[float, float, float, float, float]], nan_at: int
) -> None:
    r, fields = case
    poisoned = list(fields)
    poisoned[nan_at] = math.nan
    with pytest.raises(ValueError, match="NaN"):
        encode_command(*poisoned, r)
    with pytest.raises(ValueError, match="NaN"):
        command_encoder(r)(bytearray(8), *poisoned)


@pytest.mark.parametrize("r", [DM4310, MitRanges(12.5, 280.0, 1.0)])
def test_command_encoder_on_every_code_and_its_neighbours(r: MitRanges) -> None:
    """Every code's decoded value and the floats either side of it: where truncation flips between two codes."""
    encode, buffer = command_encoder(r), bytearray(8)
    fields = [(-r.p_max, r.p_max, 16), (-r.v_max, r.v_max, 12), (0.0, r.kp_max, 12), (0.0, r.kd_max, 12)]
    fields.append((-r.t_max, r.t_max, 12))
    for slot, (lo, hi, bits) in enumerate(fields):
        command = [lo, lo, 0.0, 0.0, lo]
        for u in range(1 << bits):
            x = uint_to_float(u, lo, hi, bits)
            for value in (math.nextafter(x, -math.inf), x, math.nextafter(x, math.inf)):
                command[slot] = value
                encode(buffer, *command)
                assert buffer == encode_command(*command, r), (slot, u, value)


def test_command_encoder_by_hand() -> None:
    # the frame of test_command_packing_by_hand, and the clamped one of test_command_fields_clamp
    buffer = bytearray(8)
    encode = command_encoder(DM4310)
    encode(buffer, 1.0, -2.0, 50.0, 1.0, 0.5)
    assert buffer == bytes([0x8A, 0x3C, 0x77, 0x71, 0x99, 0x33, 0x38, 0x65])
    encode(buffer, math.inf, -math.inf, 1e6, -1.0, 1e3)
    assert buffer == bytes([0xFF, 0xFF, 0x00, 0x0F, 0xFF, 0x00, 0x0F, 0xFF])


@given(r=ranges, u=st.tuples(st.integers(0, 0xFFFF), st.integers(0, 0xFFF), st.integers(0, 0xFFF)))
def test_state_scales_decode_like_decode_state(r: MitRanges, u: tuple[int, int, int]) -> None:
    p_lo, p_span, v_lo, v_span, t_lo, t_span = state_scales(r)
    block = (u[0] << 24 | u[1] << 12 | u[2]).to_bytes(5, "big")
    assert decode_state(block, r) == (
        u[0] * p_span / POSITION_STEPS + p_lo,
        u[1] * v_span / FIELD_STEPS + v_lo,
        u[2] * t_span / FIELD_STEPS + t_lo,
    )
