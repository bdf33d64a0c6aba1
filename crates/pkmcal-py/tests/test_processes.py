"""pkmcal in worker processes: a pool started by fork (Linux's default
before Python 3.14) or spawn, after the parent has used pkmcal, runs
calibrations (a fork copies the parent's thread pool without its threads;
the package makes its own in each process)."""

import multiprocessing

import pytest

import pkmcal

# Seconds after which a pool that has not answered is taken for hung.
HUNG_AFTER_S = 300

TRUTH = {"l11": 280.3}


def job(seed):
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 20).targets
    commands, measured = pkmcal.simulate(mech, targets, TRUTH, noise=0.002, seed=seed)
    return pkmcal.calibrate(mech, commands, measured, frame="base").parameters["l11"]


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_a_pool_of_workers_after_the_parent_used_pkmcal(method):
    if method not in multiprocessing.get_all_start_methods():
        pytest.skip(f"no {method} on this platform")
    # The parent computes in parallel first: its thread pool exists.
    mech = pkmcal.Mechanism()
    pkmcal.predict(mech, pkmcal.nominal_commands(mech, pkmcal.plan(mech, 35).targets))
    pool = multiprocessing.get_context(method).Pool(2)
    try:
        got = pool.map_async(job, [1, 2]).get(timeout=HUNG_AFTER_S)
    finally:
        pool.terminate()
        pool.join()
    assert all(abs(v - 280.3) < 0.05 for v in got), got
    # And the parent still computes.
    assert abs(job(3) - 280.3) < 0.05


def test_threads_per_process():
    pkmcal.set_threads(1)
    try:
        assert abs(job(4) - 280.3) < 0.05
    finally:
        pkmcal.set_threads(0)


def whole_fit(seed):
    mech = pkmcal.Mechanism()
    targets = pkmcal.plan(mech, 20).targets
    commands, measured = pkmcal.simulate(mech, targets, TRUTH, noise=0.002, seed=seed)
    return pkmcal.calibrate(mech, commands, measured, frame="base")


def test_a_worker_returns_a_whole_calibration():
    """The fit itself crosses the process boundary (pickled as its record)
    and is the one the parent computes from the same data."""
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(2) as pool:
        fits = list(pool.map(whole_fit, [5, 6], timeout=HUNG_AFTER_S))
    assert fits[0] == whole_fit(5) and fits[1] == whole_fit(6)
    assert fits[0] != fits[1]
    assert fits[0].std_dev["l11"] > 0
