import json

import numpy as np
import pytest

from agents.metrics import error_time_area, time_to_accuracy
from agents.plots import plot_comparison
from agents.summary import summarize
from agents.tables import format_table
from excite.stats.consistency import anees_bounds

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
        "estimator": np.full(n, "online"),
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
        "nees": rng.chisquare(3, n),
        "nees_dof": np.full(n, 3),
        "distance": 0.7 * segment,
        "time": 2.0 * segment,
    }


def last(columns: dict[str, np.ndarray], protocol: str, name: str) -> np.ndarray:
    mask = (columns["protocol"] == protocol) & (columns["segment"] == N_SEGMENTS)
    return np.asarray(columns[name], float)[mask]


def test_summary_values_match_numpy(columns):
    summary = summarize(columns, seed=1, n_boot=500)
    assert list(summary["protocols"]) == list(PROTOCOLS)
    for p in PROTOCOLS:
        s = summary["protocols"][p]["online"]
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
    collisions = {p: summary["protocols"][p]["online"]["collisions"] for p in PROTOCOLS}
    assert collisions["straight"] == {"total": 2, "per_episode": 0.25}
    assert collisions["greedy"] == {"total": 1, "per_episode": 0.125}
    assert collisions["spin"]["total"] == 0
    assert summary["oracle_sigma_min"]["median"] == pytest.approx(2.35)


def test_undetermined_flags(columns):
    protocols = summarize(columns, n_boot=100)["protocols"]
    assert protocols["straight"]["online"]["undetermined"] == ["r_L"]
    assert protocols["greedy"]["online"]["undetermined"] == []
    assert protocols["spin"]["online"]["undetermined"] == ["b"]


def test_ci_brackets_median_and_is_reproducible(columns):
    a, b = summarize(columns, seed=3), summarize(columns, seed=3)
    assert a == b
    for by_estimator in a["protocols"].values():
        s = by_estimator["online"]
        for key in ("final_max_error", "sigma_min", "ratio_to_oracle"):
            lo, hi = s[key]["ci95"]
            assert lo <= s[key]["median"] <= hi
            assert lo < hi or key != "final_max_error"
    other = summarize(columns, seed=4)
    assert other["protocols"]["greedy"]["online"]["final_max_error"]["median"] == pytest.approx(
        a["protocols"]["greedy"]["online"]["final_max_error"]["median"])
    assert other["protocols"]["greedy"]["online"]["final_max_error"]["ci95"] != (
        a["protocols"]["greedy"]["online"]["final_max_error"]["ci95"])


def test_summary_is_strict_json(columns):
    columns = dict(columns, oracle_sigma_min=np.zeros_like(columns["sigma_min"]))
    summary = summarize(columns, n_boot=200)  # ratios inf (x / 0) and nan (0 / 0)
    text = json.dumps(summary, allow_nan=False)
    assert json.loads(text) == summary
    assert summary["protocols"]["greedy"]["online"]["ratio_to_oracle"]["median"] is None
    assert summary["protocols"]["spin"]["online"]["ratio_to_oracle"]["ci95"] == [None, None]


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


@pytest.mark.slow
def test_plot_comparison_writes_four_images(columns, tmp_path):
    import matplotlib.image

    paths = plot_comparison(with_second_estimator(columns), tmp_path / "plots", arena_size=4.0)
    names = ["errors_vs_segment.png", "sigma_min_vs_segment.png", "anees_vs_segment.png",
             "trajectories.png"]
    assert [p.name for p in paths] == names
    for path in paths:
        assert path.parent == tmp_path / "plots"
        assert path.stat().st_size > 5000
        image = matplotlib.image.imread(path)
        assert np.ptp(image.reshape(-1, image.shape[-1]), axis=0).max() > 0


def matrix(columns: dict[str, np.ndarray], protocol: str, name: str,
           estimator: str = "online") -> np.ndarray:
    """(episodes, segments) of one column for one pair (the fixture's rows are in
    episode-major, segment-minor order)."""
    mask = (columns["protocol"] == protocol) & (columns["estimator"] == estimator)
    return np.asarray(columns[name], float)[mask].reshape(N_EPISODES, N_SEGMENTS)


def max_error(columns, protocol, estimator="online"):
    return np.max(np.abs([matrix(columns, protocol, f"{q}_err", estimator)
                          for q in ("r_L", "r_R", "b")]), axis=0)


def with_second_estimator(columns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The rows again as estimator "ekf", with errors 1.5x and NEES 10x (over-confident)."""
    out = {key: np.concatenate([value, value]) for key, value in columns.items()}
    second = np.arange(out["protocol"].size) >= columns["protocol"].size
    out["estimator"] = np.where(second, "ekf", out["estimator"])
    for key in ("r_L_err", "r_R_err", "b_err"):
        out[key] = np.where(second, 1.5 * out[key], out[key])
    out["nees"] = np.where(second, 10.0 * out["nees"], out["nees"])
    return out


def test_time_to_accuracy_area_and_anees_are_those_of_the_metrics(columns):
    summary = summarize(columns, n_boot=200)
    for p in PROTOCOLS:
        s = summary["protocols"][p]["online"]
        error = max_error(columns, p)
        time, distance = matrix(columns, p, "time"), matrix(columns, p, "distance")
        for key, threshold in (("0.5%", 0.005), ("0.2%", 0.002)):
            reached = time_to_accuracy(error, threshold, time, distance)
            entry = s["time_to_accuracy"][key]
            assert entry["threshold"] == threshold
            assert entry["censored"] == int(reached.censored.sum())
            for unit, values in (("segments", reached.segments), ("seconds", reached.seconds),
                                 ("metres", reached.metres)):
                median = np.median(values)
                expected = None if not np.isfinite(median) else pytest.approx(median)
                assert entry[unit]["median"] == expected, (p, key, unit)
        assert s["error_time_area"]["median"] == pytest.approx(
            np.median(error_time_area(error, time)))
        nees = matrix(columns, p, "nees")
        assert s["anees"]["final"] == pytest.approx(nees[:, -1].mean())
        assert s["anees"]["bounds"] == pytest.approx(anees_bounds(N_EPISODES, 3))
        assert s["anees"]["parameters"] == 3
    # greedy reaches 0.5% within the record in every episode; spin never reaches 0.2%.
    greedy = summary["protocols"]["greedy"]["online"]["time_to_accuracy"]
    assert greedy["0.5%"]["censored"] == 0 and greedy["0.5%"]["segments"]["median"] >= 1
    spin = summary["protocols"]["spin"]["online"]["time_to_accuracy"]["0.2%"]
    assert spin["censored"] == N_EPISODES and spin["segments"]["median"] is None


def test_paired_ratios_put_the_reference_over_each_baseline(columns):
    # greedy, 10x more accurate, renamed: it stays below 0.2% from segment 1 in most episodes
    greedy = columns["protocol"] == "greedy"
    columns = dict(columns, protocol=np.where(greedy, "learned:speed_margin=0.1",
                                              columns["protocol"]),
                   **{f"{q}_err": np.where(greedy, 0.1, 1.0) * columns[f"{q}_err"]
                      for q in ("r_L", "r_R", "b")})
    summary = summarize(columns, seed=5, n_boot=300)
    assert summary["reference"] == "learned:speed_margin=0.1"
    assert "vs_reference" not in summary["protocols"]["learned:speed_margin=0.1"]["online"]
    learned = max_error(columns, "learned:speed_margin=0.1")[:, -1]
    for baseline in ("straight", "spin"):
        ratio = summary["protocols"][baseline]["online"]["vs_reference"]
        assert ratio["episodes"] == N_EPISODES
        theirs = max_error(columns, baseline)[:, -1]
        final = ratio["final_max_error"]
        assert final["ratio"] == pytest.approx(np.median(learned) / np.median(theirs))
        assert final["ci95"][0] <= final["ratio"] <= final["ci95"][1] < 1.0
    # The baselines never reach 0.2%: a censored median gives only a bound, never a fake 0.
    learned_time = time_to_accuracy(max_error(columns, "learned:speed_margin=0.1"), 0.002)
    assert not learned_time.censored.any()
    for baseline in ("straight", "spin"):
        assert time_to_accuracy(max_error(columns, baseline), 0.002).censored.all()
        time = summary["protocols"][baseline]["online"]["vs_reference"]["time_to_0.2%"]
        assert time["ratio"] is None and time["ci95"] == [None, None]
        assert time["at_most"] == pytest.approx(np.median(learned_time.segments) / N_SEGMENTS)
    table = format_table(summary)
    assert "reference: learned:speed_margin=0.1" in table
    assert f"<{np.median(learned_time.segments) / N_SEGMENTS:.2g}" in table
    no_reference = summarize(dict(columns, protocol=np.where(
        columns["protocol"] == "learned:speed_margin=0.1", "greedy", columns["protocol"])))
    assert no_reference["reference"] is None
    assert all("vs_reference" not in s for by in no_reference["protocols"].values()
               for s in by.values())
    assert "baseline" not in format_table(no_reference)


def test_estimators_are_a_second_axis(columns):
    both = with_second_estimator(columns)
    summary = summarize(both, n_boot=200)
    for p in PROTOCOLS:
        assert list(summary["protocols"][p]) == ["online", "ekf"]
        online, ekf = (summary["protocols"][p][e] for e in ("online", "ekf"))
        assert ekf["final_max_error"]["median"] == pytest.approx(
            1.5 * online["final_max_error"]["median"])
        assert ekf["anees"]["final"] == pytest.approx(10.0 * online["anees"]["final"])
        assert ekf["anees"]["verdict"] == "over-confident"
    table = format_table(summary)
    header = table.splitlines()[0].split()
    assert header[:2] == ["protocol", "estimator"]
    rows = [line.split() for line in table.splitlines()[2:2 + 2 * len(PROTOCOLS)]]
    assert [r[:2] for r in rows[:2]] == [["greedy", "online"], ["greedy", "ekf"]]
    assert all(r[-2].endswith("+") for r in rows if r[1] == "ekf")


def test_format_table_shows_censoring(columns):
    summary = summarize(columns, n_boot=200)
    lines = format_table(summary).splitlines()
    spin = next(line for line in lines if line.startswith("spin ")).split()
    censored = summary["protocols"]["spin"]["online"]["time_to_accuracy"]["0.2%"]["censored"]
    assert spin[4] == f">{N_SEGMENTS}({censored})"
