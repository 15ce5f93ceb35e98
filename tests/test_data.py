import numpy as np
import pytest

from excite import DataError, Segments, load_segments, save_segments

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
    seg = Segments.from_array(rng.normal(size=(50, 5)) * 1e3 ** rng.uniform(-3, 3, (50, 5)))
    save_segments(tmp_path / "x.csv", seg)
    np.testing.assert_array_equal(load_segments(tmp_path / "x.csv").as_array(), seg.as_array())


@pytest.mark.parametrize(
    "content, message",
    [
        ("", "no segments"),
        (HEADER, "no segments"),
        (HEADER + "1,1,0.05,0,0\n2,2,0.1,0,0\n", "2 segment(s); at least 3"),
        (HEADER + ROWS + "1,2,3,4\n", ":5: expected 5 columns, found 4"),
        (HEADER + ROWS + "1,2,3,4,5,6\n", ":5: expected 5 columns, found 6"),
        (ROWS + "1,2,abc,4,5\n", ":4: dx_gt is not a number: 'abc'"),
        (ROWS + "1,2,3,nan,5\n", ":4: dy_gt is not finite: 'nan'"),
        (ROWS + "1,2,3,4,-inf\n", ":4: dtheta_gt is not finite: '-inf'"),
        ("1;2;3;4;5\n" + ROWS, ":1: expected 5 columns, found 1"),
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
