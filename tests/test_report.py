import json

import numpy as np
import pytest

from agents.report import format_table, plot_comparison, summarize

PROTOCOLS = ("straight", "greedy", "spin")  # order of first appearance in the rows
N_EPISODES, N_SEGMENTS = 8, 5
SCALE = {"straight": 0.05, "greedy": 0.01, "spin": 0.2}  # final max error ~ scale / K


@pytest.fixture
def columns() -> dict[str, np.ndarray]:
    """3 protocols x 8 episodes x 5 segments with known errors, sigma_min and collisions."""
    rng = np.random.default_rng(7)
    protocol, episode, segment = (
        a.ravel()
        for a in np.meshgrid(np.array(PROTOCOLS), np.arange(N_EPISODES),
                             np.arange(1, N_SEGMENTS + 1), indexing="ij")
    )
    n = protocol.size
    scale = np.array([SCALE[p] for p in protocol])
    jitter = rng.uniform(0.5, 1.5, size=(3, n))
    sign = rng.choice([-1.0, 1.0], size=(3, n))
    oracle = 2.0 + 0.1 * np.arange(N_EPISODES)  # per episode, shared by all protocols
    quality = np.array([{"straight": 0.3, "greedy": 0.8, "spin": 0.0}[p] for p in protocol])
    rel_std = np.full((3, n), 0.02)
    rel_std[2, protocol == "spin"] = np.inf  # b undetermined by spinning
    rel_std[0, protocol == "straight"] = 0.5  # r_L poorly determined
    collision = np.zeros(n, int)
    collision[[3, 12, 44]] = 1  # straight ep 0 seg 4, straight ep 2 seg 3, greedy ep 0 seg 5
    angle = 0.8 * segment + episode
    return {
        "protocol": protocol,
        "episode": episode,
        "segment": segment,
        "r_L_err": sign[0] * jitter[0] * scale / segment,
        "r_R_err": sign[1] * jitter[1] * scale / segment,
        "b_err": sign[2] * jitter[2] * scale / segment,
        "sigma_min": quality * oracle[episode] * np.sqrt(segment / N_SEGMENTS)
        * rng.uniform(0.8, 1.0, n),
        "oracle_sigma_min": oracle[episode],
        "rel_std_r_L": rel_std[0],
        "rel_std_r_R": rel_std[1],
        "rel_std_b": rel_std[2],
        "collision": collision,
        "x": 1.5 * np.cos(angle) * segment / N_SEGMENTS,
        "y": 1.5 * np.sin(angle) * segment / N_SEGMENTS,
        "theta": angle + np.pi / 2,
        "distance": 0.7 * segment,
    }


def last(columns: dict[str, np.ndarray], protocol: str, name: str) -> np.ndarray:
    mask = (columns["protocol"] == protocol) & (columns["segment"] == N_SEGMENTS)
    return np.asarray(columns[name], float)[mask]


def test_summary_values_match_numpy(columns):
    summary = summarize(columns, seed=1, n_boot=500)
    assert list(summary["protocols"]) == list(PROTOCOLS)
    for p in PROTOCOLS:
        s = summary["protocols"][p]
        assert (s["episodes"], s["segments"]) == (N_EPISODES, N_SEGMENTS)
        errors = np.abs([last(columns, p, f"{q}_err") for q in ("r_L", "r_R", "b")])
        assert s["final_max_error"]["median"] == pytest.approx(np.median(errors.max(axis=0)))
        for q, e in zip(("r_L", "r_R", "b"), errors, strict=True):
            assert s["final_error"][q] == pytest.approx(np.median(e))
        sigma = last(columns, p, "sigma_min")
        assert s["sigma_min"]["median"] == pytest.approx(np.median(sigma))
        ratio = sigma / last(columns, p, "oracle_sigma_min")
        assert s["ratio_to_oracle"]["median"] == pytest.approx(np.median(ratio))
        assert s["distance_m"] == pytest.approx(0.7 * N_SEGMENTS)
    assert summary["protocols"]["straight"]["collisions"] == {"total": 2, "per_episode": 0.25}
    assert summary["protocols"]["greedy"]["collisions"] == {"total": 1, "per_episode": 0.125}
    assert summary["protocols"]["spin"]["collisions"]["total"] == 0
    assert summary["oracle_sigma_min"]["median"] == pytest.approx(2.35)


def test_undetermined_flags(columns):
    protocols = summarize(columns, n_boot=100)["protocols"]
    assert protocols["straight"]["undetermined"] == ["r_L"]
    assert protocols["greedy"]["undetermined"] == []
    assert protocols["spin"]["undetermined"] == ["b"]


def test_ci_brackets_median_and_is_reproducible(columns):
    a, b = summarize(columns, seed=3), summarize(columns, seed=3)
    assert a == b
    for s in a["protocols"].values():
        for key in ("final_max_error", "sigma_min", "ratio_to_oracle"):
            lo, hi = s[key]["ci95"]
            assert lo <= s[key]["median"] <= hi
            assert lo < hi or key != "final_max_error"
    other = summarize(columns, seed=4)
    assert other["protocols"]["greedy"]["final_max_error"]["median"] == pytest.approx(
        a["protocols"]["greedy"]["final_max_error"]["median"])
    assert other["protocols"]["greedy"]["final_max_error"]["ci95"] != (
        a["protocols"]["greedy"]["final_max_error"]["ci95"])


def test_summary_is_strict_json(columns):
    columns = dict(columns, oracle_sigma_min=np.zeros_like(columns["sigma_min"]))
    summary = summarize(columns, n_boot=200)  # ratios inf (x / 0) and nan (0 / 0)
    text = json.dumps(summary, allow_nan=False)
    assert json.loads(text) == summary
    assert summary["protocols"]["greedy"]["ratio_to_oracle"]["median"] is None
    assert summary["protocols"]["spin"]["ratio_to_oracle"]["ci95"] == [None, None]


def test_format_table_sorted_and_narrow(columns):
    table = format_table(summarize(columns, n_boot=200))
    lines = table.splitlines()
    assert all(len(line) <= 100 for line in lines)
    positions = [table.index(f"\n{p} ") for p in PROTOCOLS]
    order = [p for _, p in sorted(zip(positions, PROTOCOLS, strict=True))]
    assert order == ["greedy", "straight", "spin"]  # ascending median final max error
    assert any(line.startswith("oracle") and "2.35" in line for line in lines)
    spin_line = next(line for line in lines if line.startswith("spin "))
    assert spin_line.rstrip().endswith("b")
    greedy_line = next(line for line in lines if line.startswith("greedy "))
    assert greedy_line.rstrip().endswith("-")


def test_format_table_fits_extreme_values(columns):
    protocol = np.where(columns["protocol"] == "spin", "straight_spin", columns["protocol"])
    columns = dict(columns, protocol=protocol,
                   r_L_err=columns["r_L_err"] * 1e3, sigma_min=columns["sigma_min"] * 1e-10,
                   distance=columns["distance"] * 40.0,
                   rel_std_r_L=np.full_like(columns["r_L_err"], np.inf),
                   rel_std_r_R=np.full_like(columns["r_L_err"], np.inf))
    table = format_table(summarize(columns, n_boot=200))
    assert "straight_spin" in table and "r_L,r_R,b" in table
    assert max(len(line) for line in table.splitlines()) <= 100


def test_plot_comparison_writes_three_images(columns, tmp_path):
    import matplotlib.image

    paths = plot_comparison(columns, tmp_path / "plots", arena_size=4.0)
    names = ["errors_vs_segment.png", "sigma_min_vs_segment.png", "trajectories.png"]
    assert [p.name for p in paths] == names
    for path in paths:
        assert path.parent == tmp_path / "plots"
        assert path.stat().st_size > 5000
        image = matplotlib.image.imread(path)
        assert np.ptp(image.reshape(-1, image.shape[-1]), axis=0).max() > 0
