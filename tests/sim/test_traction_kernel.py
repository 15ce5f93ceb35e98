"""The compiled physics kernel (envs.traction_kernel): batch-independent, bit for bit."""

import os
import re
import subprocess
import sys

import numba
import numpy as np
import pymunk.batch
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from envs.physics import traction_constants
from envs.robot import PRESETS, robot_distribution
from envs.simulation import BatchSimulation, Simulation, SimulationConfig
from envs.traction_kernel import (
    PATH_FIELDS,
    STATE_FIELDS,
    TRACTION_FIELDS,
    traction_tick,
)

DT = 1.0 / 50.0
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
COLUMN = {name: j for j, name in enumerate(STATE_FIELDS)}


def bits(values) -> np.ndarray:
    """The float64 bit patterns (so -0.0 != 0.0 and equal means identical)."""
    return np.asarray(values, dtype=np.float64).view(np.int64)


def random_batch(rng: np.random.Generator, n: int, hard: bool):
    """Kernel inputs for n robots drawn from every preset: constants, states, commands, a
    pymunk reading with the robots at shuffled rows among other bodies, and contacts.
    hard: commands and body velocities far from the motors' rolling motion (the wheels slip);
    else commands near the motor speeds and the body rolling with the motors."""
    presets = sorted(PRESETS)
    robots = [robot_distribution(presets[rng.integers(len(presets))]).sample(rng)
              for _ in range(n)]
    k = np.array([traction_constants(robot, DT) for robot in robots])
    limit = k[:, TRACTION_FIELDS.index("limit")]
    r_L, r_R, inv_b, d = (k[:, TRACTION_FIELDS.index(name)]
                          for name in ("r_L", "r_R", "inv_b", "d"))
    state = np.zeros((n, len(STATE_FIELDS)))
    motors = rng.uniform(-1, 1, (n, 2)) * limit[:, None]
    state[:, [COLUMN["w_L"], COLUMN["w_R"]]] = motors
    state[:, [COLUMN["phi_L"], COLUMN["phi_R"]]] = rng.uniform(-100, 100, (n, 2))
    m = len(robots) + 1 + int(rng.integers(0, 4))  # other bodies and the static one
    slots = rng.permutation(m)[:n].astype(np.int64)
    bodies = np.zeros((m, 6))
    bodies[:, :2] = rng.uniform(-3, 3, (m, 2))
    bodies[:, 2] = rng.uniform(-20, 20, m)
    th = bodies[slots, 2]
    if hard:
        commands = rng.uniform(-1.5, 1.5, (n, 2)) * limit[:, None]  # some beyond the limit
        velocity = rng.normal(0, 1, (n, 2))
        yaw_rate = rng.normal(0, 3, n)
    else:
        commands = motors * rng.uniform(0.99, 1.01, (n, 2))
        v_L, v_R = r_L * motors[:, 0], r_R * motors[:, 1]
        yaw_rate = (v_R - v_L) * inv_b
        forward, lateral = 0.5 * (v_L + v_R), yaw_rate * d  # body frame, at the COM
        velocity = np.stack([np.cos(th) * forward - np.sin(th) * lateral,
                             np.sin(th) * forward + np.cos(th) * lateral], axis=1)
    state[:, [COLUMN["vel_x"], COLUMN["vel_y"]]] = velocity
    state[:, COLUMN["w"]] = yaw_rate
    state[:, [COLUMN["chord_x"], COLUMN["chord_y"]]] = velocity
    bodies[slots, 3:5] = velocity + rng.normal(0, 0.05, (n, 2)) * rng.integers(0, 2, (n, 1))
    bodies[slots, 5] = yaw_rate + rng.normal(0, 0.1, n)
    contacts = rng.integers(0, 3, n) * rng.integers(0, 2, n)
    began = rng.integers(0, 2, n).astype(bool)
    return k, state, commands, bodies, slots, contacts.astype(np.int64), began


def run_kernel(k, state, commands, bodies, slots, contacts, began, tick, n_ticks, m):
    """One kernel call on copies; returns everything it writes."""
    state, began = state.copy(), began.copy()
    collided = np.zeros(len(state), dtype=bool)
    velocities = np.full((m, 3), np.nan)
    path = np.full((n_ticks + 1, len(state), len(PATH_FIELDS)), np.nan)
    traction_tick(k, state, commands, DT, bodies.ravel(), slots, contacts, began, collided,
                  velocities, path, tick, n_ticks)
    return state, began, collided, velocities[slots], path


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 9), hard=st.booleans(),
       n_ticks=st.integers(0, 3), data=st.data())
@settings(max_examples=80, deadline=None)
def test_kernel_on_n_robots_is_the_kernel_on_each_alone(seed, n, hard, n_ticks, data):
    """Robot i of a call on N robots gets exactly (bit for bit) what a call on robot i alone
    gives it: every output of the kernel, for any robots, commands, contacts and tick."""
    tick = data.draw(st.integers(0, n_ticks))
    batch = random_batch(np.random.default_rng(seed), n, hard)
    m = len(batch[3])
    together = run_kernel(*batch, tick, n_ticks, m)
    k, state, commands, bodies, slots, contacts, began = batch
    for i in range(n):
        one = slice(i, i + 1)
        alone = run_kernel(k[one], state[one], commands[one], bodies, slots[one],
                           contacts[one], began[one], tick, n_ticks, m)
        for a, b in zip(together[:4], alone[:4], strict=True):
            np.testing.assert_array_equal(bits(a[one]), bits(b))
        np.testing.assert_array_equal(bits(together[4][:, one]), bits(alone[4]))


def test_rolls_exactly_inside_the_friction_circles_and_slips_outside():
    """Gentle commands on a rolling body: the new twist is exactly the wheels' rolling twist.
    Hard commands on a body moving its own way: the friction caps bind, so most robots end off
    their rolling twist."""
    for hard in (False, True):
        k, state, commands, bodies, slots, contacts, began = random_batch(
            np.random.default_rng(3), 40, hard)
        out = run_kernel(k, state, commands, bodies, slots, np.zeros_like(contacts),
                         np.zeros_like(began), 0, 1, len(bodies))[0]
        limit = k[:, TRACTION_FIELDS.index("limit")][:, None]
        motors = state[:, [COLUMN["w_L"], COLUMN["w_R"]]]
        alpha = k[:, TRACTION_FIELDS.index("alpha")][:, None]
        new_motors = motors + (np.clip(commands, -limit, limit) - motors) * alpha
        np.testing.assert_array_equal(out[:, [COLUMN["w_L"], COLUMN["w_R"]]], new_motors)
        r_L, r_R, inv_b = (k[:, TRACTION_FIELDS.index(name)] for name in ("r_L", "r_R", "inv_b"))
        rolling_w = (r_R * new_motors[:, 1] - r_L * new_motors[:, 0]) * inv_b
        rolled = out[:, COLUMN["w"]] == rolling_w
        assert rolled.all() if not hard else rolled.sum() < len(rolled) / 2


def test_the_robot_loop_is_not_vectorised():
    """No vector math in the compiled kernel: a vectorised loop would call vector sin/cos
    (SVML), whose results differ from libm's, and the batch would stop matching one robot.
    Checked on a fresh compilation (numba cannot inspect cached code)."""
    batch = random_batch(np.random.default_rng(0), 2, True)
    run_kernel(*batch, 0, 1, len(batch[3]))
    fresh = numba.njit(traction_tick.py_func)
    fresh.compile(traction_tick.signatures[0])
    signature = fresh.signatures[0]
    ir, asm = fresh.inspect_llvm(signature), fresh.inspect_asm(signature)
    assert "@llvm.cos.f64" in ir and "@llvm.sin.f64" in ir, "scalar libm sin/cos expected"
    assert not re.search(r"<\d+ x double>", ir), "vector code in the kernel"
    assert "svml" not in asm.lower()


@pytest.mark.slow
def test_the_compiled_kernel_is_reused_from_the_disk_cache(tmp_path):
    """A fresh process compiles the kernel once into the cache directory; the next process
    loads it from there instead of compiling."""
    code = ("import numpy as np\n"
            "from envs.simulation import Simulation\n"
            "from envs.robot import robot_distribution\n"
            "from envs.traction_kernel import traction_tick\n"
            "sim = Simulation()\n"
            "sim.reset(robot_distribution({}).nominal(), np.random.default_rng(0))\n"
            "sim.run_segment(5.0, 6.0, 0.1)\n"
            "print(sum(traction_tick.stats.cache_hits.values()),"
            " sum(traction_tick.stats.cache_misses.values()))\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path),
           "PYTHONPATH": os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")])}
    runs = [subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                           text=True, check=True).stdout.split() for _ in range(2)]
    assert runs == [["0", "1"], ["1", "0"]]
    assert any(tmp_path.rglob("*.nbi")) and any(tmp_path.rglob("*.nbc"))


def test_the_drives_make_no_pymunk_batch_buffers_per_run(monkeypatch):
    """pymunk never frees a pymunk.batch.Buffer's C arrays, so the drives make their buffers
    once and reuse them, through wall contacts (fresh bodies, a fresh space) and resets."""
    made = []
    original = pymunk.batch.Buffer.__init__
    monkeypatch.setattr(pymunk.batch.Buffer, "__init__",
                        lambda self: (made.append(1), original(self))[1])
    config = SimulationConfig(arena_width=1.5, arena_height=1.5)  # small: walls reached often
    robot = robot_distribution({}).nominal()
    single, batch = Simulation(config), BatchSimulation(config, 3)
    commands = np.random.default_rng(4).uniform(-15, 15, (40, 3, 2))
    contacts = 0
    for episode in range(2):
        single.reset(robot, np.random.default_rng(episode), pose=(0.0, 0.0, 0.0))
        for i in range(3):
            batch.reset(i, robot, np.random.default_rng(episode), pose=(0.0, 0.0, 0.0))
        for step, command in enumerate(commands):
            contacts += single.run_segment(*command[0], 0.5).collision
            contacts += batch.run_segment(command, 0.5).collision.sum()
            if step == 0 and episode == 0:
                first = len(made)
    assert contacts > 20, "the robots must touch the walls"
    assert len(made) == first == 6  # each drive's three, made at its first run
