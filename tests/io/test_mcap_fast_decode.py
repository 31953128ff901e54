"""Messages are decoded by msgspec where it takes them and by json where it
does not (:func:`graphpos.io.mcap_drive._decode_messages`); either way the
columns are exactly what json.loads gives message by message: the same values
bit for bit (-0.0, subnormals, integers beyond 2**53, null, NaN and 1e999),
the same errors. And the CSV export writes what the csv module wrote."""

from __future__ import annotations

import csv
import io
import json

import msgspec
import numpy as np
import pytest

from graphpos.drive import Channel, Drive, TagMap
from graphpos.errors import FileFormatError
from graphpos.estimate import CSV_COLUMNS, Estimate
from graphpos.io import read_drive, read_estimates, write_drive
from graphpos.io.exports import csv_text
from graphpos.io.mcap_container import read_mcap_contents
from graphpos.io.json_rules import JsonRuleError, number_column, number_rows
from graphpos.io.mcap_drive import _ESTIMATE_FIELDS, _decode_columns

NAMES = ("t_s", "accel_x_mps2", "yaw_rate_radps")
AWKWARD = [0.1, 1e-300, -1e-300, 5e-324, -5e-324, -0.0, 0.0, 1e16, 1e-5, 1e-4, 123456789012345678.0, 2.0**53 + 2,
           1.7976931348623157e308, -1.7976931348623157e308, 2.2250738585072014e-308, 1 / 3, -2 / 3, 100.0, 1e22, 1e23]


def random_floats(n: int, seed: int = 0) -> np.ndarray:
    """Finite float64 values of every exponent (random bit patterns)."""
    bits = np.random.default_rng(seed).integers(0, 2**64, n, dtype=np.uint64, endpoint=False)
    values = bits.view(np.float64)
    return values[np.isfinite(values)]


def per_message(payloads: list[bytes], names) -> dict[str, np.ndarray]:
    """The columns as json.loads gives them, message by message (the reader before msgspec)."""
    rows = []
    for i, payload in enumerate(payloads):
        try:
            rows.append(json.loads(payload))
        except ValueError as exc:
            raise FileFormatError(f"x, message {i}: not valid JSON ({exc})") from None
        if type(rows[-1]) is not dict:
            raise FileFormatError(f"x, message {i}: expected a JSON object, got {type(rows[-1]).__name__}")
    return {name: number_rows([r.get(name) for r in rows], name, 0, 4) if name == "cov_en_m2"
            else number_column([r.get(name) for r in rows], name, 0) for name in names}


def outcome(decode):
    try:
        return "ok", decode()
    except (FileFormatError, JsonRuleError) as exc:
        return type(exc).__name__, str(exc)


def assert_same_columns(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys()
    for name in a:
        x, y = a[name], b[name]
        assert x.shape == y.shape and x.dtype == y.dtype == np.float64, name
        same = x.view(np.uint64) == y.view(np.uint64)  # bit for bit: -0.0 is not 0.0, NaN is the same NaN
        assert same.all(), (name, x[~same][:5], y[~same][:5])


def assert_same_estimates(written: list[Estimate], read: list[Estimate]) -> None:
    """The estimates read back are the ones written, bit for bit (NaN is written as null: it reads back as NaN of any sign)."""
    for est, got in zip(written, read, strict=True):
        for field in _ESTIMATE_FIELDS:
            want, have = getattr(est, field), getattr(got, field)
            assert (want is None) == (have is None), field
            if want is not None:
                assert_same_columns({field: np.where(np.isnan(want), np.nan, want)}, {field: have})


def assert_reads_as_json(payloads: list[bytes]) -> None:
    """The reader's columns are json's bit for bit, or both refuse with the same message."""
    fast, slow = outcome(lambda: _decode_columns(payloads, NAMES, "x")[0]), outcome(lambda: per_message(payloads, NAMES))
    assert fast[0] == slow[0], (payloads[:2], fast, slow)
    if fast[0] == "ok":
        assert_same_columns(fast[1], slow[1])
    else:
        assert fast[1] == slow[1]


def canonical(columns: dict[str, list[str]]) -> list[bytes]:
    """Messages in the layout graphpos writes, from the value texts."""
    n = len(next(iter(columns.values())))
    return [("{" + ",".join(f'"{k}":{v[i]}' for k, v in columns.items()) + "}").encode() for i in range(n)]


def test_messages_as_graphpos_writes_them_are_read_bit_exact():
    values = np.concatenate([random_floats(6000), AWKWARD])
    n = values.size // 3
    texts = [list(map(repr, values[i * n : (i + 1) * n].tolist())) for i in range(3)]
    texts[1][::7] = ["null"] * len(texts[1][::7])
    payloads = canonical(dict(zip(NAMES, texts)))
    decoded, present = _decode_columns(payloads, NAMES, "x")
    assert present == set(NAMES)
    assert_same_columns(decoded, per_message(payloads, NAMES))
    assert np.isnan(decoded["accel_x_mps2"][::7]).all()


@pytest.mark.parametrize("text", [
    # valid JSON numbers that graphpos does not write, read as JSON reads them
    "1E5", "1e+05", "1e-05", "-0", "0", "-0.0", "0e0", "-0e0", "-0.5", "0.25", "10", "-10", "1e05", "1E-0",
    "12345678901234567890123", "9007199254740993", "-9007199254740993", "1.0e-310", "2.4703282292062328e-324",
    "2.4703282292062327e-324", "0.000000000000000000000000001", "1e999", "-1e999", "1" + "0" * 400, "1" + "0" * 400 + ".0",
    "null",
    # not JSON numbers: refused as the JSON parser refuses them
    "01", "-01", "00", "-00", "1.", ".5", "-.5", "+1", "1e", "1e+", "1e-", "e5", "1e5e5", "1.2.3", "1e5.5", "1.5e",
    "nul", "nulll", "nullnull", "null1", "1null", "NaN", "nan", "Infinity", "-Infinity", "-", "--1", "1-2", "1+2", "",
    "0x10", "1_0", "true", "false", '"1"', "[1]", "1 ", " 1", "1\n", "\u00b9",
])
def test_any_value_text_gives_what_json_gives(text):
    column = [repr(v) for v in AWKWARD]
    for row in (0, 7, len(column) - 1):
        texts = {"t_s": column, "accel_x_mps2": column[::-1], "yaw_rate_radps": list(column)}
        texts["yaw_rate_radps"][row] = text
        texts["t_s"][row] = text if row == 0 else texts["t_s"][row]
        payloads = canonical(texts)
        assert_reads_as_json(payloads)


def test_random_value_texts_give_what_json_gives():
    """Texts of the bytes numbers and null are made of, at random: read as json reads them, or refused as it refuses them."""
    rng = np.random.default_rng(7)
    alphabet = np.frombuffer(b"0123456789.eE+-nul0-", dtype=np.uint8)
    for _ in range(3000):
        text = alphabet[rng.integers(0, alphabet.size, rng.integers(1, 7))].tobytes().decode()
        payloads = canonical({"t_s": ["0.5", text], "accel_x_mps2": [text, "-0.0"], "yaw_rate_radps": ["1e-300", text]})
        assert_reads_as_json(payloads)


@pytest.mark.parametrize("payloads", [
    [b'{"t_s":0.0,"yaw_rate_radps":1.0,"accel_x_mps2":2.0}'],  # other field order
    [b'{"t_s":0.0,"accel_x_mps2":2.0}'],  # a field missing
    [b'{"t_s":0.0,"accel_x_mps2":2.0,"yaw_rate_radps":1.0,"extra":3}'],  # a field more
    [b'{"t_s":0.0,"accel_x_mps2":2.0,"yaw_rate_radps":1.0,"t_s":5.0}'],  # a field twice (the last one counts)
    [b'{"t_s": 0.0,"accel_x_mps2":2.0,"yaw_rate_radps":1.0}'],  # spacing
    [b'{"t_s":0.0,\n"accel_x_mps2":2.0,"yaw_rate_radps":1.0}'],
    [b'{"t_s":0.0,"accel_x_mps2":\x012.0,"yaw_rate_radps":1.0}'],  # a control character
    [b'{"t_s":0.0,"accel_x_mps2":2.0,"yaw_rate_radps":1.0}', b'{"t_s":1.0,"accel_x_mps2":2.0}'],
    [b'{"t_s":0.0,"accel_x_mps2":2.0,"yaw_rate_radps":1.0}{"t_s":1.0,"accel_x_mps2":2.0,"yaw_rate_radps":1.0}'],
    [b'{"t_s":0.0,"accel_x_mps2":2.0,"yaw_rate_radps":1.0}', b""],
    [b'{"t_s":0.0,"accel_x_mps2":2.0,"yaw_rate_radps":1.0'],
    [b'{"t_s":0.0,"acel_x_mps2":2.0,"yaw_rate_radps":1.0}'],  # a misspelt name
    [b'{"t_s":0.0,"accel_x_mps2":"\\ud800","yaw_rate_radps":1.0}'],  # a lone surrogate: json takes it, msgspec not
    [b'{"t_s":NaN,"accel_x_mps2":1e999,"yaw_rate_radps":-Infinity}'],  # json's non-standard numbers
    [b'[1.0, 2.0]'],  # not an object
    [b'{"t_s":0.0,"accel_x_mps2":[2.0],"yaw_rate_radps":1.0}'],
    [b'{"t_s":0.0,"accel_x_mps2":2.0,"yaw_rate_radps":\xff}'],
])
def test_other_messages_give_what_json_gives(payloads):
    assert_reads_as_json(payloads)


def awkward_drive(n: int = 400) -> Drive:
    rng = np.random.default_rng(3)
    t = np.arange(n) * 0.01 + 0.1
    accel = np.resize(np.array([0.1, 1e-300, -1e-300, 5e-324, -0.0, 0.0, np.nan, 49.999999999999993, -1 / 3]), n)
    yaw_rate = rng.uniform(-10, 10, n) * 10.0 ** rng.integers(-320, 0, n)
    tag_ids = np.array([0, 2**53, 2**53 - 1, 12345678901])
    tags = TagMap(tag_ids, np.array([0.1, 1e-300, -0.0, 3.0]), np.array([1.0, -1.0, 2.0, 5e-324]), np.array([1, -1, 1, -1]),
                  np.array([0, 1, 2, 2**53]))
    channels = {
        "imu": Channel("imu", {"t_s": t, "accel_x_mps2": accel, "accel_y_mps2": accel[::-1].copy(), "yaw_rate_radps": yaw_rate}),
        "wheel": Channel("wheel", {"t_s": t, "speed_mps": np.resize([0.1, -0.0, 1e-300, 99.99999999999999], n)}),
        "rfid": Channel("rfid", {"t_s": t[::10], "tag_id": np.resize(tag_ids, t[::10].size).astype(np.float64),
                                 "rss": np.resize([np.nan, 255.0, 0.1], t[::10].size)}),
    }
    return Drive("awkward", channels, tags=tags)


def test_awkward_drive_round_trips_bit_exact(tmp_path):
    drive = awkward_drive()
    covs = np.resize(np.array([[[0.1, -0.0], [1e-300, 5e-324]], [[np.nan, 1e308], [-1e308, 1.0]]]), (40, 2, 2))
    t = np.arange(40) * 0.1 + 0.1
    estimates = [
        Estimate("with-cov", t, np.resize([0.1, -0.0], 40), np.resize([1e-300, 2.0], 40), None, None, np.resize([np.nan, 0.5], 40),
                 cov_en_m2=covs),
        Estimate("without", t, np.resize([1 / 3], 40), np.resize([-5e-324], 40)),
    ]
    path = tmp_path / "awkward.mcap"
    write_drive(path, drive, estimates)
    contents = read_mcap_contents(path)
    for channel in contents.channels.values():  # every message graphpos wrote is one msgspec takes
        if contents.schemas[channel.schema_id].name.startswith("graphpos."):
            for payload in contents.payloads[channel.id]:
                assert msgspec.json.decode(payload) == json.loads(payload)
    back = read_drive(path)
    for kind, channel in drive.channels.items():
        assert_same_columns(channel.columns, back.channels[kind].columns)
    assert_same_estimates(estimates, read_estimates(path))


def old_csv_text(estimate: Estimate) -> str:
    """csv_text as it was, row by row through the csv module."""
    table = estimate.table()
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for row in zip(*[table[c] for c in CSV_COLUMNS]):
        writer.writerow(["" if not np.isfinite(v) else repr(float(v)) for v in row])
    return buf.getvalue()


@pytest.mark.parametrize("n", [0, 1, 500])
def test_csv_is_written_as_before(n):
    values = np.resize(np.concatenate([AWKWARD, [np.nan, np.inf, -np.inf], random_floats(200, seed=1)]), n)
    cov = np.resize(values[::-1], (n, 2, 2)) if n else np.zeros((0, 2, 2))
    estimate = Estimate("x", np.arange(n) * 0.1, values, values[::-1].copy(), values, None, values, cov_en_m2=cov)
    text = csv_text(estimate)
    assert text == old_csv_text(estimate)
    cells = [line.split(",") for line in text.splitlines()[1:]]
    east = np.array([float(c[1]) if c[1] else np.nan for c in cells], dtype=np.float64)
    finite = np.isfinite(values)
    assert (east[finite].view(np.uint64) == values[finite].view(np.uint64)).all() and np.isnan(east[~finite]).all()



@pytest.mark.parametrize("odd_row", [0, 4, 9])
def test_batches_join_up(monkeypatch, odd_row):
    monkeypatch.setattr("graphpos.io.mcap_drive._BATCH_ROWS", 3)
    column = [repr(v) for v in AWKWARD[:10]]
    payloads = canonical({"t_s": column, "accel_x_mps2": column[::-1], "yaw_rate_radps": column})
    spaced = payloads[odd_row].replace(b":", b": ")
    decoded, _ = _decode_columns(payloads[:odd_row] + [spaced] + payloads[odd_row + 1 :], NAMES, "x")
    assert_same_columns(decoded, per_message(payloads, NAMES))
    bad = payloads[odd_row].replace(b'"yaw_rate_radps":', b'"yaw_rate_radps":"')[:-1] + b'"}'  # a string
    with pytest.raises(JsonRuleError) as error:
        _decode_columns(payloads[:odd_row] + [bad] + payloads[odd_row + 1 :], NAMES, "x")
    assert error.value.row == odd_row and error.value.field == "yaw_rate_radps"
