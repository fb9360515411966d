"""The Python CAN decoders fuzzed with Hypothesis (issue 15, deliver 1): any frame, on our
ids or others, any DLC, any bytes, any order.

What may happen to a frame that does not fit: `decode` raises KeyError (an id that is not
ours), cantools' DecodeError or ValueError, nothing else; `ResultCollector.push` and the
CLI's `format_frame` never raise at all; `parse_response` raises only ValueError. The
number of examples is ALACS_FUZZ_EXAMPLES (default 2000 per property: about 15 s in all);
Hypothesis shrinks any finding to a minimal frame and prints it with the seed.
"""

from __future__ import annotations

import os

import can
from cantools.database.errors import DecodeError
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import alacs_can
from alacs_can import sdo

EXAMPLES = int(os.environ.get("ALACS_FUZZ_EXAMPLES", "2000"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

DB = alacs_can.load_database(alacs_can.DEFAULT_NODE_ID)
OUR_IDS = sorted(m.frame_id for m in DB.messages)


def frames() -> st.SearchStrategy[can.Message]:
    """Mostly our ids (where the decoders have work to do), some others, a few extended."""
    ident = st.one_of(st.sampled_from(OUR_IDS), st.integers(0, 0x7FF))
    return st.builds(
        lambda i, ext, data: can.Message(arbitration_id=i | (0x10000 if ext else 0), is_extended_id=ext,
                                         data=data, dlc=len(data)),
        ident, st.sampled_from([False] * 9 + [True]),
        st.binary(min_size=0, max_size=8))


@FUZZ
@given(frames())
def test_decode_raises_only_its_documented_errors(msg: can.Message) -> None:
    for choices in (True, False):
        try:
            out = alacs_can.decode(DB, msg, choices=choices)
        except (KeyError, DecodeError, ValueError):
            continue
        assert isinstance(out, dict)
    try:
        alacs_can.decode_raw(DB, msg)
    except (KeyError, DecodeError, ValueError):
        pass


@FUZZ
@given(st.lists(frames(), max_size=40))
def test_result_collector_never_raises(msgs: list[can.Message]) -> None:
    collector = alacs_can.ResultCollector(DB, max_results=4)
    for m in msgs:
        result = collector.push(m)
        if result is not None:
            assert result.object_count >= 0
            assert len(collector.results) <= 4


@FUZZ
@given(frames())
def test_cli_formats_any_frame(msg: can.Message) -> None:
    from alacs_cli.main import format_frame  # the technician's monitor and replay --print

    msg.timestamp = 1.0
    line = format_frame(DB, msg, t0=0.0)
    assert isinstance(line, str) and "\n" not in line


@FUZZ
@given(st.binary(min_size=0, max_size=12))
def test_sdo_response_parser(data: bytes) -> None:
    try:
        r = sdo.parse_response(data)
    except ValueError:
        assert len(data) != 8
        return
    assert 0 <= r.value() <= 0xFFFFFFFF
