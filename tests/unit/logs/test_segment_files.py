import json
import re

import numpy as np
import pytest

from excite import DataError, Segments, load_segments, save_segments
from excite.logs.segments import load_segment_files

HEADER = "dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt\n"
ROWS = "1,1,0.05,0,0\n2,1,0.07,0.01,-0.17\n-1,1,0,0,0.33\n"


def write(tmp_path, text: str | bytes, name="log.csv"):
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def test_reads_with_and_without_header_and_comments(tmp_path):
    with_header = load_segments(write(tmp_path, HEADER + ROWS, "a.csv"))
    without = load_segments(write(tmp_path, "# a comment\n\n" + ROWS, "b.csv"))
    np.testing.assert_array_equal(with_header.as_array(), without.as_array())
    assert len(with_header) == 3
    np.testing.assert_array_equal(with_header.dtheta, [0, -0.17, 0.33])


def test_round_trip_is_exact(tmp_path, rng):
    # every digit of values over nine decades (within what a robot drives: segment_bounds)
    seg = Segments.from_array(rng.normal(size=(50, 5)) * 10.0 ** rng.uniform(-9, 0, (50, 5)))
    save_segments(tmp_path / "x.csv", seg)
    np.testing.assert_array_equal(load_segments(tmp_path / "x.csv").as_array(), seg.as_array())


@pytest.mark.parametrize(
    "content, message",
    [
        ("", "no segments"),
        (HEADER, "no segments"),
        (HEADER + "1,1,0.05,0,0\n2,2,0.1,0,0\n", "2 segment(s); at least 3"),
        (HEADER + ROWS + "1,2,3,4\n", ":5: expected 5 columns, found 4"),
        ("0,0,0,0,0,0\n1,1,1,0.05,0,0\n", ":1: 6 columns and no header: a segment CSV has 5 "
         "(dphi_L,dphi_R,dx_gt,dy_gt,dtheta_gt; a header names any others), a time-series "
         "CSV needs its header (t,phi_L,phi_R,x,y,theta)"),
        (HEADER + ROWS + "1,2,3,4,5,6\n", ":5: expected 5 columns, found 6"),
        (ROWS + "1,2,abc,4,5\n", ":4: dx_gt is not a number: 'abc'"),
        (ROWS + "1,2,3,nan,5\n", ":4: dy_gt is not finite: 'nan'"),
        (ROWS + "1,2,3,4,-inf\n", ":4: dtheta_gt is not finite: '-inf'"),
        ("1;2;3;4;5\n" + ROWS, ":2: expected 5 columns separated by semicolons, found 1"),
        (HEADER + "1,2,3,4,5\n" + HEADER + ROWS, ":3: dphi_L is not a number"),
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "binary data"),
        (HEADER.encode() + b"1,2,3,4,\xff\xfe\n", ":2: not UTF-8 text"),
    ],
)
def test_malformed_input_names_file_and_line(tmp_path, content, message):
    path = write(tmp_path, content)
    with pytest.raises(DataError) as info:
        load_segments(path)
    text = str(info.value)
    assert text.startswith(str(path)) and message in text
    assert "\n" not in text


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        load_segments(tmp_path / "nope.csv")
    with pytest.raises(DataError, match="is a directory"):
        load_segments(tmp_path)


def test_segments_validate_arrays():
    with pytest.raises(DataError, match="same length"):
        Segments([1, 2], [1, 2], [1], [1, 2], [1, 2])
    with pytest.raises(DataError, match="NaN or inf"):
        Segments([1.0], [np.nan], [1.0], [1.0], [1.0])
    with pytest.raises(DataError, match=r"\(N, 5\)"):
        Segments.from_array(np.zeros((3, 4)))
    seg = Segments.from_array(np.zeros((4, 5)))
    with pytest.raises(ValueError):
        seg.dx[0] = 1.0  # read-only
    assert len(seg[1:3]) == 2


# --- Censi tuple files -----------------------------------------------------------------------

# Three segments: objects 1 and 2 on line 2, object 3 spread over lines 3-7, extra keys.
TUPLES = (
    "# Censi tuples\n"
    '{"T": 0.5, "phi_l": 2.0, "phi_r": -3.0, "sm": [0.1, -0.02, 0.3]} '
    '{"phi_r": 7, "T": 0.1, "phi_l": 3, "sm": [0, 0, -1.5], "id": 4, "extra": {"a": [1]}}\n'
    "{\n"
    '  "T": 2,\n'
    '  "phi_l": -0.25, "phi_r": 0.125,\n'
    '  "sm": [-1e-3, 2.5e-4, 6.5]\n'
    "}\n"
)
TUPLES_EXPECTED = np.array(
    [
        [2.0 * 0.5, -3.0 * 0.5, 0.1, -0.02, 0.3],
        [3 * 0.1, 7 * 0.1, 0.0, 0.0, -1.5],
        [-0.25 * 2, 0.125 * 2, -1e-3, 2.5e-4, 6.5],
    ]
)
GOOD = '{"T": 1, "phi_l": 1, "phi_r": 2, "sm": [0.1, 0, 0.2]}'


def test_tuple_file_is_read_exactly(tmp_path):
    seg = load_segments(write(tmp_path, TUPLES, "log.tuple"))
    np.testing.assert_array_equal(seg.as_array(), TUPLES_EXPECTED)
    assert seg.dphi_L[1] == 3 * 0.1 != 0.3  # phi * T, computed as the product
    assert isinstance(seg, Segments) and len(seg) == 3


def test_tuple_file_round_trip_random_layout(tmp_path, rng):
    n = 40
    T = rng.uniform(0.01, 3.0, n)
    phi = rng.normal(size=(n, 2)) * 10
    sm = rng.normal(size=(n, 3))
    separators = ["\n", " ", "\t", "\n\n  ", "\r\n", ""]
    parts = []
    for i in range(n):
        obj = {"sm": sm[i].tolist(), "phi_r": phi[i, 1], "stamp": i, "T": T[i],
               "phi_l": phi[i, 0]}
        parts.append(json.dumps(obj, indent=2 if i % 3 == 0 else None))
        parts.append(separators[i % len(separators)])
    seg = load_segments(write(tmp_path, "".join(parts), "run.tuple"))
    expected = np.column_stack([phi[:, 0] * T, phi[:, 1] * T, sm])
    np.testing.assert_array_equal(seg.as_array(), expected)


def test_tuple_file_detected_by_content(tmp_path):
    path = write(tmp_path, "\n  \n# comment {not json}\n   " + TUPLES.split("\n", 1)[1],
                 "log.txt")
    np.testing.assert_array_equal(load_segments(path).as_array(), TUPLES_EXPECTED)
    # A CSV with another suffix stays a CSV ...
    csv = load_segments(write(tmp_path, "# {comment}\n" + HEADER + ROWS, "log.txt"))
    np.testing.assert_array_equal(csv.dphi_R, [1, 1, 1])
    # ... and the .tuple suffix wins over the content.
    path = write(tmp_path, HEADER + ROWS, "log.tuple")
    with pytest.raises(DataError, match=re.escape(f"{path}: object 1 (line 1): invalid JSON")):
        load_segments(path)


def test_a_json_array_of_tuples_is_refused_with_the_format_s_words(tmp_path):
    """Tuples written as one JSON array (json.dump of a list) were read as a CSV of one row
    and hundreds of columns; they are a tuple file the reader refuses, saying why."""
    objects = [{"T": 0.5, "phi_l": 2.0 + k, "phi_r": -3.0, "sm": [0.1, -0.02, 0.3]}
               for k in range(4)]
    path = write(tmp_path, json.dumps(objects), "log.json")
    with pytest.raises(DataError, match=re.escape(
            f"{path}: object 1 (line 1): expected a JSON object, found a list (a tuple file "
            "is a stream of objects, not a JSON array)")):
        load_segments(path)


def test_tuple_comments_and_crlf_between_objects(tmp_path):
    text = "# head\r\n" + GOOD + "  # after\r\n\r\n" + GOOD + "\r\n# mid\r\n" + GOOD + "\r\n"
    seg = load_segments(write(tmp_path, text, "c.tuple"))
    np.testing.assert_array_equal(seg.as_array(), [[1, 2, 0.1, 0, 0.2]] * 3)
    bad = text + '{"T": 0, "phi_l": 1, "phi_r": 1, "sm": [0, 0, 0]}'
    path = write(tmp_path, bad, "c.tuple")
    with pytest.raises(DataError, match=re.escape(f"{path}: object 4 (line 7): ")):
        load_segments(path)


def _obj(**changes) -> str:
    obj = {"T": 0.5, "phi_l": 1.0, "phi_r": 2.0, "sm": [0.1, 0.0, 0.2]}
    obj.update(changes)
    return json.dumps({k: v for k, v in obj.items() if v is not _DROP})


_DROP = object()
# Objects 1-3 on lines 1-2, the object under test is object 4 on line 3 (unless stated).
PREFIX = GOOD + " " + GOOD + "\n" + GOOD + "\n"


@pytest.mark.parametrize(
    "content, where, message",
    [
        (PREFIX + '{"T": 1, "phi_l": 1,, }', "object 4 (line 3)",
         "invalid JSON: Expecting property name enclosed in double quotes at line 3 column 21"),
        (PREFIX + '{\n"T": 1,\n"phi_l": 1\n"phi_r": 2}', "object 4 (line 3)",
         "invalid JSON: Expecting ',' delimiter at line 6 column 1"),
        (PREFIX + '{"T": 1, "sm": [1, 2', "object 4 (line 3)", "invalid JSON: Expecting"),
        (PREFIX + "garbage", "object 4 (line 3)", "invalid JSON: Expecting value at line 3 "),
        (PREFIX + GOOD + ", " + GOOD, "object 5 (line 3)", "invalid JSON: Expecting value"),
        (PREFIX + "[" + GOOD + "]", "object 4 (line 3)",
         "expected a JSON object, found a list (a tuple file is a stream of objects"),
        (PREFIX + "42", "object 4 (line 3)", "expected a JSON object, found a number"),
        (PREFIX + '"x"', "object 4 (line 3)", "expected a JSON object, found a string"),
        (GOOD + " null", "object 2 (line 1)", "expected a JSON object, found null"),
        (PREFIX + _obj(T=_DROP), "object 4 (line 3)", 'missing key "T"'),
        (PREFIX + _obj(phi_l=_DROP), "object 4 (line 3)", 'missing key "phi_l"'),
        (PREFIX + _obj(phi_r=_DROP), "object 4 (line 3)", 'missing key "phi_r"'),
        (PREFIX + _obj(sm=_DROP), "object 4 (line 3)", 'missing key "sm"'),
        (PREFIX + _obj(T="1"), "object 4 (line 3)", '"T" must be a number, found "1"'),
        (PREFIX + _obj(phi_l=None), "object 4 (line 3)", '"phi_l" must be a number, found null'),
        (PREFIX + _obj(phi_r=True), "object 4 (line 3)", '"phi_r" must be a number, found true'),
        (PREFIX + _obj(T=False), "object 4 (line 3)", '"T" must be a number, found false'),
        (PREFIX + _obj(sm=[1, "x", 0]), "object 4 (line 3)",
         '"sm"[1] must be a number, found "x"'),
        (PREFIX + _obj(sm=[True, 0, 0]), "object 4 (line 3)",
         '"sm"[0] must be a number, found true'),
        (PREFIX + _obj(phi_l=float("nan")), "object 4 (line 3)", '"phi_l" is not finite: NaN'),
        (PREFIX + _obj(T=float("inf")), "object 4 (line 3)", '"T" is not finite: Infinity'),
        (PREFIX + _obj(sm=[0, 0, float("-inf")]), "object 4 (line 3)",
         '"sm"[2] is not finite: -Infinity'),
        (PREFIX + _obj(phi_r=10**400), "object 4 (line 3)", '"phi_r" is not finite: 1000'),
        (PREFIX + _obj(phi_l=1e300, T=1e10), "object 4 (line 3)", '"phi_l" * "T" overflows'),
        (PREFIX + _obj(T=0), "object 4 (line 3)", '"T" must be > 0 s, found 0'),
        (PREFIX + _obj(T=-0.5), "object 4 (line 3)", '"T" must be > 0 s, found -0.5'),
        (PREFIX + _obj(sm=[1, 2]), "object 4 (line 3)",
         '"sm" must be a list of 3 numbers, found [1, 2]'),
        (PREFIX + _obj(sm=[1, 2, 3, 4]), "object 4 (line 3)",
         '"sm" must be a list of 3 numbers, found [1, 2, 3, 4]'),
        (PREFIX + _obj(sm=5), "object 4 (line 3)", '"sm" must be a list of 3 numbers, found 5'),
        (PREFIX + _obj(sm={"x": 1, "y": 2, "theta": 3}), "object 4 (line 3)",
         '"sm" must be a list of 3 numbers, found {"x": 1'),
        (_obj(T=-1) + "\n" + GOOD, "object 1 (line 1)", '"T" must be > 0 s'),
    ],
)
def test_malformed_tuple_names_file_object_and_line(tmp_path, content, where, message):
    path = write(tmp_path, content, "log.tuple")
    with pytest.raises(DataError, match="^" + re.escape(f"{path}: {where}: {message}")) as info:
        load_segments(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "content, message",
    [
        ("", "no segments"),
        ("  \n# only a comment\n", "no segments"),
        (GOOD + "\n" + GOOD, "2 segment(s); at least 3"),
        (b"{\x00\x01", "binary data"),
    ],
)
def test_tuple_file_without_enough_segments(tmp_path, content, message):
    path = write(tmp_path, content, "log.tuple")
    with pytest.raises(DataError, match="^" + re.escape(f"{path}: {message}")):
        load_segments(path)


# --- several files ---------------------------------------------------------------------------


def test_load_segment_files_concatenates_in_order(tmp_path):
    csv = write(tmp_path, HEADER + ROWS, "a.csv")
    tup = write(tmp_path, TUPLES, "b.tuple")
    csv_rows = load_segments(csv).as_array()
    both = load_segment_files([csv, str(tup)])
    np.testing.assert_array_equal(both.as_array(), np.vstack([csv_rows, TUPLES_EXPECTED]))
    reverse = load_segment_files((tup, csv))
    np.testing.assert_array_equal(reverse.as_array(), np.vstack([TUPLES_EXPECTED, csv_rows]))
    assert len(load_segment_files([csv])) == 3


def test_load_segment_files_minimum_applies_to_total(tmp_path):
    csv = write(tmp_path, HEADER + "1,1,0.05,0,0\n2,1,0.07,0.01,-0.17\n", "a.csv")
    tup = write(tmp_path, GOOD + "\n" + GOOD, "b.tuple")
    one = write(tmp_path, GOOD, "c.tuple")
    for path in (csv, tup):  # 2 segments each: too few alone, enough together
        with pytest.raises(DataError, match="2 segment"):
            load_segments(path)
    seg = load_segment_files([csv, tup])
    assert len(seg) == 4
    np.testing.assert_array_equal(seg.dphi_R, [1, 1, 2, 2])
    with pytest.raises(DataError) as info:
        load_segment_files([one])
    assert str(info.value).startswith(f"{one}: 1 segment(s); at least 3")
    one_csv = write(tmp_path, "1,1,0.05,0,0\n", "d.csv")
    with pytest.raises(DataError) as info:
        load_segment_files([one, one_csv])
    assert str(info.value).startswith(f"{one}, {one_csv}: 2 segment(s) in total; at least 3")


def test_load_segment_files_every_file_must_parse(tmp_path):
    good = write(tmp_path, HEADER + ROWS, "a.csv")
    empty = write(tmp_path, "", "empty.tuple")
    header_only = write(tmp_path, HEADER, "h.csv")
    bad = write(tmp_path, GOOD + " " + _obj(sm=[1, 2]), "bad.txt")
    with pytest.raises(DataError, match="^" + re.escape(f"{empty}: no segments")):
        load_segment_files([good, empty])
    with pytest.raises(DataError, match="^" + re.escape(f"{header_only}: no segments")):
        load_segment_files([good, header_only])
    with pytest.raises(DataError, match="^" + re.escape(f"{bad}: object 2 (line 1): \"sm\"")):
        load_segment_files([good, bad])
    with pytest.raises(DataError, match="no such file"):
        load_segment_files([good, tmp_path / "missing.tuple"])
    with pytest.raises(DataError, match="no segment files"):
        load_segment_files([])
    with pytest.raises(TypeError, match="sequence of paths"):
        load_segment_files(str(good))


def _chained_segments(n: int = 6) -> Segments:
    rows = np.arange(n * 5, dtype=float).reshape(n, 5) + 1.0
    subs = np.arange(n * 3, dtype=float).reshape(n, 3)
    return Segments(*rows.T, t_start=np.arange(n, dtype=float), t_end=np.arange(n) + 1.0,
                    chained=np.r_[False, np.ones(n - 1, dtype=bool)],
                    sub_dphi_L=subs, sub_dphi_R=-subs)


def test_selecting_segments_keeps_a_chain_only_between_neighbours():
    seg = _chained_segments()
    picked = seg[np.array([True, True, False, True, True, True])]
    assert picked.chained.tolist() == [False, True, False, True, True]
    np.testing.assert_array_equal(picked.t_start, [0, 1, 3, 4, 5])
    assert picked.sub_dphi_L.shape == (5, 3)
    assert seg[[3, 2]].chained.tolist() == [False, False]  # reversed order is no chain


def test_concatenate_breaks_chains_between_parts_and_pads_substeps():
    a, b = _chained_segments(4), _chained_segments(3)
    b = Segments(*b.as_array().T, t_start=b.t_start, t_end=b.t_end, chained=b.chained,
                 sub_dphi_L=b.sub_dphi_L[:, :2], sub_dphi_R=b.sub_dphi_R[:, :2])
    both = Segments.concatenate([a, b])
    assert both.chained.tolist() == [False, True, True, True, False, True, True]
    assert both.sub_dphi_L.shape == (7, 3) and np.all(both.sub_dphi_L[4:, 2] == 0)
    assert both.substep_counts.tolist() == [3, 3, 3, 3, 2, 2, 2]  # padding is not a sub-step
    assert both[[5, 1]].sub_count.tolist() == [2, 3]
    plain = Segments.concatenate([a, Segments.from_array(a.as_array())])
    assert plain.sub_dphi_L is None and plain.t_start is None
    assert plain.chained.tolist() == [False, True, True, True, False, False, False, False]


def test_optional_columns_are_checked():
    rows = np.ones((3, 5))
    with pytest.raises(DataError, match="t_start"):
        Segments(*rows.T, t_start=np.ones(2))
    with pytest.raises(DataError, match="given together"):
        Segments(*rows.T, sub_dphi_L=np.ones((3, 2)))
    with pytest.raises(DataError, match="sub_count"):
        Segments(*rows.T, sub_dphi_L=np.ones((3, 2)), sub_dphi_R=np.ones((3, 2)),
                 sub_count=np.array([1, 2, 3]))
