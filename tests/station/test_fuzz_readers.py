"""Property-based fuzzing (hypothesis) of the two file readers that take input from
outside: the trace reader (station/recording/trace.py) and the parameter-file reader
(station/outputs/params_file.py). Any byte string, and any JSON edit of a good file, either
reads or raises the project's error type with a one-line message; never another
exception."""
import json
import os
import warnings

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from calibration.errors import StationError
from station.outputs.params_file import checksum, read_params
from station.recording.trace import read_trace

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TRACES = os.path.join(ROOT, "fixtures", "traces")
# derandomized: the suite stays deterministic; explore further with
# `pytest --hypothesis-seed=N -p no:cacheprovider` and a larger max_examples
FUZZ = settings(max_examples=150, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])

# any JSON value, including the awkward ones: huge and tiny numbers, big integers,
# unicode, nesting
json_values = st.recursive(
    st.none() | st.booleans() | st.floats(allow_nan=False, allow_infinity=False)
    | st.integers(min_value=-(10 ** 30), max_value=10 ** 30) | st.text(max_size=8)
    | st.sampled_from([1e300, -1e300, 10 ** 400, 5e-324, -0.0, "", "agebot-sm", "fit"]),
    lambda children: st.lists(children, max_size=4)
    | st.dictionaries(st.text(max_size=6), children, max_size=4),
    max_leaves=12)


def _lines(name):
    with open(os.path.join(TRACES, name), "rb") as f:
        return f.read().splitlines(keepends=True)


TRACE_LINES = {name: _lines(name) for name in ("sm-distance-tilt.jsonl", "pm-fk.jsonl",
                                               "sm-self-redundancy.jsonl")}


def reads_or_one_line_error(reader, path):
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return reader(path)
    except StationError as e:
        text = str(e)
        assert text and "\n" not in text, repr(text)
        return None


def _paths(doc):
    """Every (container, key) in a JSON document."""
    out = []
    stack = [doc]
    while stack:
        node = stack.pop()
        items = node.items() if isinstance(node, dict) else enumerate(node)
        for k, v in items:
            out.append((node, k))
            if isinstance(v, (dict, list)):
                stack.append(v)
    return out


def _mutate(data, doc):
    """Replace, delete or add one value somewhere in ``doc`` (in place)."""
    paths = _paths(doc)
    container, key = data.draw(st.sampled_from(paths)) if paths else (doc, None)
    action = data.draw(st.sampled_from(["replace", "delete", "add"]))
    if action == "replace" and key is not None:
        container[key] = data.draw(json_values)
    elif action == "delete" and key is not None:
        del container[key]
    elif isinstance(container, dict):
        container[data.draw(st.text(max_size=8))] = data.draw(json_values)
    else:
        container.append(data.draw(json_values))


# -- traces ------------------------------------------------------------------------------
@pytest.mark.parametrize("reader, name", [(read_trace, "t.jsonl"), (read_params, "p.json")],
                         ids=["trace", "params"])
@FUZZ
@given(raw=st.binary(max_size=600))
def test_reader_on_any_bytes(tmp_path, reader, name, raw):
    p = tmp_path / name
    p.write_bytes(raw)
    reads_or_one_line_error(reader, p)


@FUZZ
@given(data=st.data())
def test_trace_reader_on_edited_records(tmp_path, data):
    name = data.draw(st.sampled_from(sorted(TRACE_LINES)))
    lines = list(TRACE_LINES[name][:8])
    k = data.draw(st.integers(0, len(lines) - 1))
    rec = json.loads(lines[k])
    for _ in range(data.draw(st.integers(1, 3))):
        _mutate(data, rec)
    lines[k] = (json.dumps(rec) + "\n").encode()
    if data.draw(st.booleans()):          # also cut the file somewhere
        cut = data.draw(st.integers(0, len(lines)))
        lines = lines[:cut]
    p = tmp_path / "t.jsonl"
    p.write_bytes(b"".join(lines))
    trace = reads_or_one_line_error(read_trace, p)
    if trace is not None:
        assert trace.header["record"] == "header"


numbers = (st.floats(allow_nan=False, allow_infinity=False)
           | st.integers(min_value=-(10 ** 500), max_value=10 ** 500)
           | st.sampled_from([1e300, -1e300, 10 ** 400, -1329.1, 1e12, 1e13]))


@FUZZ
@given(data=st.data())
def test_trace_reader_on_any_number(tmp_path, data):
    """Any JSON number in any numeric field of the header, reference or a pose."""
    lines = list(TRACE_LINES["sm-distance-tilt.jsonl"][:5])
    k = data.draw(st.integers(0, len(lines) - 1))
    rec = json.loads(lines[k])
    leaves = [(c, key) for c, key in _paths(rec)
              if isinstance(c[key], (int, float)) and not isinstance(c[key], bool)]
    for c, key in data.draw(st.lists(st.sampled_from(leaves), min_size=1, max_size=3)):
        c[key] = data.draw(numbers)
    lines[k] = (json.dumps(rec) + "\n").encode()
    p = tmp_path / "t.jsonl"
    p.write_bytes(b"".join(lines))
    reads_or_one_line_error(read_trace, p)


@FUZZ
@given(data=st.data())
def test_trace_reader_on_spliced_bytes(tmp_path, data):
    """Bytes flipped, inserted or dropped anywhere in a good trace."""
    raw = bytearray(b"".join(TRACE_LINES["sm-distance-tilt.jsonl"][:6]))
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(raw) - 1))
        op = data.draw(st.sampled_from(["flip", "insert", "drop"]))
        if op == "flip":
            raw[i] = data.draw(st.integers(0, 255))
        elif op == "insert":
            raw[i:i] = data.draw(st.binary(min_size=1, max_size=4))
        else:
            del raw[i]
    p = tmp_path / "t.jsonl"
    p.write_bytes(bytes(raw))
    reads_or_one_line_error(read_trace, p)


# -- parameter files ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def good_params(tmp_path_factory):
    from station.fitting.batch import calibrate_trace

    out = tmp_path_factory.mktemp("fuzz") / "p.json"
    calibrate_trace(os.path.join(TRACES, "sm-distance.jsonl"), out=str(out))
    return json.loads(out.read_text())


@FUZZ
@given(data=st.data())
def test_params_reader_on_edited_documents(tmp_path, good_params, data):
    """One to three edits anywhere, the checksum recomputed so that the edits reach
    the structure and value checks (else the checksum alone would refuse them)."""
    doc = json.loads(json.dumps(good_params))
    for _ in range(data.draw(st.integers(1, 3))):
        _mutate(data, doc)
    if isinstance(doc, dict) and data.draw(st.booleans()):
        try:
            doc["checksum"] = checksum(doc)
        except (TypeError, ValueError):      # a value the canonical JSON cannot hold
            pass
    p = tmp_path / "p.json"
    p.write_text(json.dumps(doc))
    got = reads_or_one_line_error(read_params, p)
    if got is not None:                       # what reads is usable as a parameter file
        for name, par in got["parameters"].items():
            assert isinstance(par["value"], (int, float)) and not isinstance(par["value"], bool)
        assert got["checksum"] == checksum(got)
