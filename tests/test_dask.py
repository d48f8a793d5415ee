"""Dask clusters (bdipole_cl/dask.py): a LocalCluster of 2 worker processes."""
import contextlib
import os
import shutil
import threading
import time

import numpy as np
import OpenImageIO as oiio
import pytest

pytest.importorskip("distributed")        # a dependency of the test extra: present in CI

import dask.array as da
from distributed import Client, LocalCluster
from test_scene import SCENE, make_files

import bdipole_cl
from bdipole_cl import dask as bdask
from bdipole_cl.cluster import not_finished
from bdipole_cl.signals import sigint_ignored_by_children
from bdipole_cl import scene as scenes
from bdipole_cl.apps.cli import main as cli_main
from bdipole_cl.apps.demo import write_exr
from bdipole_cl.io.partials import partial_files


@pytest.fixture(autouse=True)
def default_device():
    """The process on the default device, as the workers are: a texture-varying blur's near
    field is chosen by the device's gather costs, so a bake on PoCL (the last device another
    test file's fixture left as the default) and one on Intel's runtime differ within the
    blur's error bound, not within round-off."""
    bdipole_cl.use_device(None)


@pytest.fixture(scope="module")
def client():
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                           dashboard_address=":0")
    with Client(cluster) as c:
        yield c
    cluster.close()


def read(path):
    inp = oiio.ImageInput.open(str(path))
    px = np.asarray(inp.read_image(oiio.FLOAT))
    inp.close()
    return px


def scene_copy(root, name):
    d = root / name
    shutil.copytree(root / "src", d)
    return d / "scene.toml"


@pytest.fixture
def two_scenes(tmp_path):
    src = tmp_path / "src"
    make_files(src, tiles=("1001", "1002", "1003"))
    (src / "scene.toml").write_text(SCENE.replace("METHOD", ""))
    return scene_copy(tmp_path, "local"), scene_copy(tmp_path, "cluster")


def outputs(scene_path):
    return {p.name: read(p) for p in sorted((scene_path.parent / "out").iterdir())}


def test_a_cluster_bake_equals_the_in_process_bake(client, two_scenes):
    local, cluster = two_scenes
    assert scenes.load(local).plan().run().exit_code == 0
    report = bdask.bake_on_cluster(scenes.load(cluster).plan(), client, progress=False)
    assert report.exit_code == 0, report.summary()
    a, b = outputs(local), outputs(cluster)
    assert a.keys() == b.keys() and len(a) == 7          # skin x3, grey x1, exitance x3
    for name in a:
        if name.startswith("exitance"):            # the blur: within float round-off
            np.testing.assert_allclose(b[name], a[name], rtol=1e-6, atol=1e-8)
        else:                                      # the inversion: bit for bit
            np.testing.assert_array_equal(b[name], a[name])
    # up-to-date checks run in this process before anything is sent: a second bake sends none
    again = bdask.bake_on_cluster(scenes.load(cluster).plan(), client, progress=False)
    assert {r.status for r in again.results} == {"skipped"}


def test_a_worker_killed_mid_job_and_a_job_failing_once_still_complete(client, two_scenes,
                                                                       tmp_path):
    _, cluster = two_scenes
    marker_kill, marker_fail = tmp_path / "killed", tmp_path / "failed"

    def flaky(job, device=None):
        # the first skin job kills its worker, leaving a writer's temporary file behind; the
        # first grey job raises; both are run again by Dask
        if job.name == "skin" and not marker_kill.exists():
            marker_kill.write_text("x")
            os.makedirs(os.path.dirname(job.output), exist_ok=True)
            stem = os.path.splitext(os.path.basename(job.output))[0]
            partial = f".{stem}.partial-{os.getpid()}-2.exr"       # this worker's, which dies
            open(os.path.join(os.path.dirname(job.output), partial), "wb").close()
            os._exit(1)
        if job.name == "grey" and not marker_fail.exists():
            marker_fail.write_text("x")
            raise RuntimeError("a passing fault")
        return bdask.run_on_worker(job, device)

    report = bdask.bake_on_cluster(scenes.load(cluster).plan(), client, progress=False,
                                   run=flaky)
    assert marker_kill.exists() and marker_fail.exists(), report.summary()
    assert report.exit_code == 0, report.summary()
    out = cluster.parent / "out"
    assert not [p for p in out.iterdir() if ".partial-" in p.name]
    assert all(not partial_files(out / n) for n in os.listdir(out))


def test_lazy_blur_equals_the_in_memory_blur(client):
    e = np.random.default_rng(3).uniform(0, 1, (96, 80, 3)).astype(np.float32)
    e[40:44, 30:34] = 20.0
    for border in ("clamp", "zero", "wrap"):
        kw = dict(albedo=(0.8, 0.6, 0.4), mfp=(3.0, 2.0, 1.0), eta=1.4, border=border)
        want = bdipole_cl.blur(e, **kw)
        lazy = bdask.blur(da.from_array(e, chunks=(40, 35, 3)), **kw)
        got = lazy.compute()
        # fft per block against fft of the whole image: float64 round-off of the transforms
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * e.max())


def test_lazy_blur_of_an_image_smaller_than_the_kernel(client):
    """An image no larger than the kernel's radius (no overlap of that depth fits) is blurred
    as one block: the in-memory result, HxW in and HxW out, under every border rule."""
    e = np.random.default_rng(4).uniform(0, 1, (12, 9)).astype(np.float32)
    for border in ("clamp", "zero", "wrap"):
        want = bdipole_cl.blur(e, albedo=0.5, mfp=2.0, border=border)
        got = bdask.blur(da.from_array(e, chunks=(4, 9)), albedo=0.5, mfp=2.0,
                         border=border).compute()
        assert got.shape == e.shape
        np.testing.assert_array_equal(got, want)


def test_lazy_inversion_equals_the_in_memory_one(client):
    rd = np.random.default_rng(4).uniform(1e-4, 0.999, (64, 48, 3)).astype(np.float32)
    arr = da.from_array(rd, chunks=(20, 20, 3))
    alpha, rho = bdask.invert_albedo(arr, 1.4, return_rho=True)
    want_a, want_rho = bdipole_cl.invert_albedo(rd, 1.4, return_rho=True)
    np.testing.assert_array_equal(alpha.compute(), want_a)
    np.testing.assert_array_equal(rho.compute(), want_rho)
    sa, ss = bdask.albedo_to_coefficients(arr, (1.0, 0.5, 0.25), 1.4)
    want = bdipole_cl.albedo_to_coefficients(rd, (1.0, 0.5, 0.25), 1.4)
    np.testing.assert_array_equal(sa.compute(), want[0])
    np.testing.assert_array_equal(ss.compute(), want[1])
    mfp = np.random.default_rng(5).uniform(0.5, 4.0, (64, 48)).astype(np.float32)
    want = bdipole_cl.albedo_to_coefficients(rd, mfp, 1.4)      # an HxW map: every channel
    for given in (mfp, da.from_array(mfp, chunks=(20, 20))):
        sa, ss = bdask.albedo_to_coefficients(arr, given, 1.4)
        np.testing.assert_array_equal(sa.compute(), want[0])
        np.testing.assert_array_equal(ss.compute(), want[1])


def test_file_blur_on_the_cluster_equals_the_local_file_blur(client, tmp_path):
    from bdipole_cl.io.blur_file import blur_file
    e = np.random.default_rng(5).uniform(0, 1, (70, 40, 3)).astype(np.float32)
    write_exr(tmp_path / "e.exr", e, ("R", "G", "B"))
    kw = dict(albedo=(0.8, 0.6, 0.4), mfp=(2.0, 1.0, 0.5), eta=1.4)
    blur_file(tmp_path / "e.exr", tmp_path / "local.exr", **kw)
    stale = tmp_path / ".cluster.bands-killed"     # what a killed run of this output left
    stale.mkdir()
    (stale / "band00000.exr").write_bytes(b"partial")
    n = bdask.blur_file_on_cluster(tmp_path / "e.exr", tmp_path / "cluster.exr", client,
                                   max_memory=40 * 3 * 4 * 10 * 30, progress=False, **kw)
    assert n > 2                                   # in bands, with halos
    np.testing.assert_allclose(read(tmp_path / "cluster.exr"), read(tmp_path / "local.exr"),
                               rtol=1e-6, atol=1e-7)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cluster.exr", "e.exr", "local.exr"]


def test_cli_bake_on_a_local_cluster(tmp_path, capsys):
    make_files(tmp_path)
    (tmp_path / "scene.toml").write_text(SCENE.replace("METHOD", ""))
    assert cli_main(["bake", str(tmp_path / "scene.toml"), "--scheduler", "local:2",
                     "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "dask dashboard: http" in out and "5 done, 0 failed, 0 skipped" in out
    assert cli_main(["bake", str(tmp_path / "scene.toml"), "--scheduler", "local:0"]) == 2
    assert "expected local:N with N >= 1" in capsys.readouterr().err
    for value, said in (("", "expected local:N"), ("abc", "expected local:N"),
                        ("inproc://x", "not a scheduler address")):
        with pytest.raises(SystemExit) if not value else contextlib.nullcontext():
            code = cli_main(["bake", str(tmp_path / "scene.toml"), "--scheduler", value])
            assert code == 2          # an empty one ran in this process, unsaid
        err = capsys.readouterr().err
        assert said in err and len(err.strip().splitlines()) == 1, err


def test_a_stop_request_cancels_the_unfinished_cluster_jobs(client, two_scenes):
    """SIGINT/SIGTERM during a cluster bake: what has not finished is cancelled within a
    poll, reported "cancelled", and no job runs to its end after the request."""
    from bdipole_cl.signals import STOP
    _, cluster = two_scenes

    def slow(job, device=None):
        time.sleep(4)                  # a running task is not interrupted; it is abandoned
        raise RuntimeError("should have been cancelled")

    timer = threading.Timer(1.0, STOP.set)
    timer.start()
    t0 = time.monotonic()
    try:
        report = bdask.bake_on_cluster(scenes.load(cluster).plan(), client, progress=False,
                                       run=slow)
    finally:
        timer.cancel()
        STOP.clear()
    assert time.monotonic() - t0 < 10, "the bake waited for its jobs after the stop request"
    assert {r.status for r in report.results} == {"cancelled"}, report.summary()
    assert not (cluster.parent / "out").exists() or not os.listdir(cluster.parent / "out")


def test_a_usd_stage_bakes_on_the_cluster_with_the_same_records(client, tmp_path):
    pytest.importorskip("pxr")
    from test_usd_scene import write_stage
    local, cluster = write_stage(tmp_path / "local"), write_stage(tmp_path / "cluster")
    assert scenes.load(local).plan().run().exit_code == 0
    report = bdask.bake_on_cluster(scenes.load(cluster).plan(), client, progress=False)
    assert report.exit_code == 0, report.summary()
    for name in ("skin.1001.exr", "skin.1002.exr", "marble.exr"):     # bit for bit
        np.testing.assert_array_equal(read(cluster.parent / "bdipole" / name),
                                      read(local.parent / "bdipole" / name))
    # the constant material's coefficients and the layer: the same (paths are relative)
    for name in ("bdipole.usda", "bdipole.mtlx"):
        assert (cluster.parent / "bdipole" / name).read_text() == \
            (local.parent / "bdipole" / name).read_text()
    again = bdask.bake_on_cluster(scenes.load(cluster).plan(), client, progress=False)
    assert {r.status for r in again.results} == {"skipped"}


def test_band_folders_of_an_output_are_its_own(tmp_path):
    """A blur of m.exr removes what a killed run of it left (.m.bands-XXXX), never the live
    band folder of m.bands-x.exr's blur (.m.bands-x.bands-XXXX), nor one of m[1].exr's."""
    own = tmp_path / ".m.bands-abc123_x"
    others = [tmp_path / ".m.bands-x.bands-abcd1234", tmp_path / ".m[1].bands-abcd1234"]
    for p in [own, *others]:
        p.mkdir()
    assert bdask.remove_band_folders(tmp_path / "m.exr") == 1
    assert not own.exists() and all(p.exists() for p in others)


def test_cluster_blur_refuses_a_texture_of_an_outside_window_first_and_counts_clamps(
        client, tmp_path):
    """On a cluster as in one process: a --texture output whose data window reaches outside
    its display window is refused before any band is sent; and values clamped to the half
    range are counted (returned to the CLI's line), not only warned of."""
    from bdipole_cl.io.images import TextureError
    spec = oiio.ImageSpec(16, 16, 3, "float")
    spec.x = spec.y = -2
    spec.full_width = spec.full_height = 16
    out = oiio.ImageOutput.create(str(tmp_path / "dw.exr"))
    assert out.open(str(tmp_path / "dw.exr"), spec)
    out.write_image(np.full((16, 16, 3), 0.5, np.float32))
    out.close()
    kw = dict(albedo=0.8, mfp=1.0, eta=1.4, progress=False)
    with pytest.raises(TextureError, match="cannot be a texture"):
        bdask.blur_file_on_cluster(tmp_path / "dw.exr", tmp_path / "t.exr", client,
                                   texture=True, **kw)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dw.exr"]      # no band folder
    write_exr(tmp_path / "hot.exr", np.full((16, 16, 3), 1e6, np.float32), ("R", "G", "B"))
    clamped = {}
    bdask.blur_file_on_cluster(tmp_path / "hot.exr", tmp_path / "h.exr", client, half=True,
                               on_invalid="clamp", clamped=clamped, **kw)
    assert clamped.get("half range") == 16 * 16 * 3       # values: every channel of each texel


def test_lazy_functions_name_a_bad_value_where_it_is_in_the_array():
    """Each block is checked on its own: the error names the value's index in the whole
    array (the block's origin added), as the in-memory function does."""
    import dask
    rd = np.full((64, 64, 3), 0.5, np.float32)
    rd[40, 50, 1] = np.nan
    with dask.config.set(scheduler="synchronous"):
        for call in (lambda a: bdask.invert_albedo(a, 1.4),
                     lambda a: bdask.albedo_to_coefficients(a, 1.0, 1.4)[0]):
            with pytest.raises(bdipole_cl.InvalidInputError, match=r"index \(40, 50, 1\)"):
                call(da.from_array(rd, chunks=(16, 16, 3))).compute()
        with pytest.raises(bdipole_cl.InvalidInputError, match="x=50, y=40, channel 1"):
            bdask.blur(da.from_array(rd, chunks=(32, 32, 3)), albedo=0.8, mfp=2.0).compute()


def test_workers_start_with_sigint_blocked_and_this_process_keeps_its_handler():
    """A Ctrl-C reaches the whole process group: the workers must not see it (the command
    cancels them itself), but this process must, also while the cluster starts (it was
    ignored here for the whole start, so a Ctrl-C then was lost)."""
    import multiprocessing
    import signal
    handler = signal.getsignal(signal.SIGINT)
    with sigint_ignored_by_children():
        assert signal.getsignal(signal.SIGINT) is handler
        child = multiprocessing.get_context("spawn").Process(target=time.sleep, args=(5,))
        child.start()
    try:
        with open(f"/proc/{child.pid}/status") as f:
            blocked = int(next(line for line in f if line.startswith("SigBlk:")).split()[1],
                          16)
        assert blocked & (1 << (signal.SIGINT - 1)), hex(blocked)
    finally:
        child.terminate()
        child.join()
    assert not signal.pthread_sigmask(signal.SIG_BLOCK, []) & {signal.SIGINT}


def test_a_task_that_finished_as_the_run_stopped_is_reported_done(tmp_path):
    """A stop can cancel the run just as a task's output is renamed into place: that output
    is whole and new, so its row says done, not "nothing written"; the file that was there
    before the run (or none) is still cancelled."""
    from bdipole_cl.io.verify import file_identity
    out = tmp_path / "a.exr"
    assert not_finished("a", str(out), None).status == "cancelled"      # none
    write_exr(out, np.ones((4, 4, 3), np.float32), ("R", "G", "B"))
    before = file_identity(out)
    assert not_finished("a", str(out), before).status == "cancelled"    # the old one
    write_exr(tmp_path / "new.exr", np.zeros((4, 4, 3), np.float32), ("R", "G", "B"))
    os.replace(tmp_path / "new.exr", out)                                      # as a writer
    done = not_finished("a", str(out), before)
    assert done.status == "ok" and "as the run was stopped" in done.notes[0]


def test_lazy_inversions_keep_double_and_take_channel_chunks():
    """double=True gives float64 (equal to the in-memory call), and per-channel etas work on
    an array chunked one channel per block (its channels are merged into one chunk)."""
    rd = np.random.default_rng(3).uniform(0.05, 0.95, (8, 6, 3))
    arr = da.from_array(rd, chunks=(4, 3, 1))
    etas = (1.3, 1.4, 1.5)
    got = bdask.invert_albedo(arr, etas, double=True).compute()
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, bdipole_cl.invert_albedo(rd, etas, double=True))
    sa, _ = bdask.albedo_to_coefficients(arr, 2.0, etas)
    np.testing.assert_array_equal(sa.compute(), bdipole_cl.albedo_to_coefficients(rd, 2.0,
                                                                                   etas)[0])


def test_jobs_go_to_workers_with_absolute_paths_and_sendable_keys(tmp_path, monkeypatch):
    """A worker's working folder is not the command's: every path of a job is made absolute
    before it is sent (relative ones named another worker's files on a tcp cluster, and one
    not written by this tool was replaced); a task key of a Latin-1 file name is text msgpack
    can send (it lost the scheduler, and the batch)."""
    from bdipole_cl.cluster import absolute, task_key
    from bdipole_cl.jobs.job import Job
    monkeypatch.chdir(tmp_path)
    job = Job("invert", "in/a.exr", "out/a.exr", {"albedo": "in/a.exr", "mfp": "in/m.exr"},
              None)
    sent = absolute(job)
    assert (sent.source, sent.output) == (str(tmp_path / "in/a.exr"), str(tmp_path / "out/a.exr"))
    assert sent.inputs == {"albedo": str(tmp_path / "in/a.exr"),
                           "mfp": str(tmp_path / "in/m.exr")}
    key = task_key("invert", 3, os.fsdecode(b"caf\xe9.exr"), "run")
    assert key == "invert-3-caf\\udce9.exr-run" and key.encode("utf-8")


def test_a_worker_dying_at_start_up_fails_every_job_named_with_the_summary(tmp_path, capsys):
    """A worker process that dies as ``--scheduler local:1`` starts (here a Dask preload that
    exits with status 3) gave 'RuntimeError: Nanny failed to start (an unexpected error)', no
    summary, no job named; an unreachable scheduler the same. Now the error line says what
    and what to try, and every job fails in the summary, named (exit 1)."""
    import dask
    make_files(tmp_path, tiles=("1001",))
    (tmp_path / "scene.toml").write_text(SCENE.replace("METHOD", ""))
    (tmp_path / "die.py").write_text("import os\n\n\ndef dask_setup(worker):\n    os._exit(3)\n")
    argv = ["bake", str(tmp_path / "scene.toml"), "--no-progress", "--scheduler"]
    with dask.config.set({"distributed.worker.preload": [str(tmp_path / "die.py")]}):
        assert cli_main(argv + ["local:1"]) == 1
    out, err = capsys.readouterr()
    assert "the local cluster did not start: a worker process exited as it started " \
        "(status 3)" in err and len(err.strip().splitlines()) == 1, err
    assert "0 done, 3 failed, 0 skipped" in out
    assert f"{tmp_path / 'tex' / 'skin.1001.exr'}: not run: --scheduler local:1: the local " \
        f"cluster did not start" in out
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        assert cli_main(argv + ["tcp://127.0.0.1:9"]) == 1
    out, err = capsys.readouterr()
    assert "cannot reach the scheduler" in err and "0 done, 3 failed" in out, (out, err)


def test_invert_and_blur_name_their_files_when_the_cluster_does_not_start(tmp_path, capsys,
                                                                          monkeypatch):
    """The file batch and the cluster blur: the same start-up failure fails each file, named
    (no cluster is started here: ``connect`` raises as a dead start does)."""
    from bdipole_cl import cluster
    from bdipole_cl.cluster import ClusterStartError

    @contextlib.contextmanager
    def dead(scheduler, memory_limit=None):
        raise ClusterStartError(f"--scheduler {scheduler}: the local cluster did not start: "
                                f"a worker process exited as it started (status 3); ...",
                                f"--scheduler {scheduler}: the local cluster did not start")
        yield
    monkeypatch.setattr(cluster, "connect", dead)
    make_files(tmp_path, tiles=("1001",))
    a = tmp_path / "tex" / "skin.1001.exr"
    assert cli_main(["invert", str(a), "-o", str(tmp_path / "o.exr"), "--no-progress",
                     "--scheduler", "local:1"]) == 1
    out, err = capsys.readouterr()
    assert f"{a}: not run: --scheduler local:1: the local cluster did not start" in out
    assert "0 done, 1 failed" in out and not (tmp_path / "o.exr").exists()
    e = tmp_path / "light" / "irr.1001.exr"
    assert cli_main(["blur", str(e), "-o", str(tmp_path / "m.exr"), "--albedo", "0.5",
                     "--mfp", "2", "--no-progress", "--scheduler", "local:1"]) == 1
    err = capsys.readouterr().err
    assert f"{e}: not blurred, nothing written: --scheduler local:1: the local cluster did " \
        f"not start" in err and not (tmp_path / "m.exr").exists()


def test_lazy_blur_with_a_stretch_equals_the_in_memory_blur(client, tmp_path):
    """``bdipole_cl.dask.blur(..., stretch=, charts=)`` as ``bdipole_cl.blur`` takes them (a
    cylinder's two charts 1:2 along u, from its mesh): one task per channel, the whole image
    each, chunked back as the input; equal to the in-memory blur within its bound (each
    channel's plan is the in-memory plan's channel), under each chart border rule; an HxW
    image too. A stretch of another size is refused before any task runs."""
    pytest.importorskip("pxr")
    from stretch_meshes import cylinder_stage
    (tile, _), = bdipole_cl.stretch_maps(cylinder_stage(tmp_path / "cyl.usda"), size=48)
    e = np.zeros((48, 48, 3), np.float32)
    e[24, 10], e[20, 35], e[5:9, 30:33] = 1.0, 0.5, 2.0
    kw = dict(albedo=(0.8, 0.6, 0.4), mfp=(1.2, 0.6, 0.3), eta=(1.4, 1.4, 1.3), tol=1e-3)
    for charts in ("clamp", "zero", "none"):
        want, info = bdipole_cl.blur(e, stretch=tile, charts=charts, return_info=True, **kw)
        lazy = bdask.blur(da.from_array(e, chunks=(20, 16, 3)), stretch=tile, charts=charts,
                          **kw)
        assert lazy.chunks == da.from_array(e, chunks=(20, 16, 3)).chunks
        got = lazy.compute()
        for c in range(3):
            bound = 2 * info.channels[c].error_bound * float(e.max()) * kw["albedo"][c]
            assert np.max(np.abs(got[..., c] - want[..., c])) <= bound, (charts, c)
        assert got[..., 0].sum() > 0
    grey = bdask.blur(da.from_array(e[..., 0], chunks=16), albedo=0.8, mfp=1.2,
                      stretch=tile).compute()
    np.testing.assert_allclose(grey, bdipole_cl.blur(e[..., 0], albedo=0.8, mfp=1.2,
                                                     stretch=tile), rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match=r"shape \(48, 48\); expected \(40, 48\)"):
        bdask.blur(da.from_array(e[:40], chunks=16), stretch=tile, **kw)


def test_a_stretch_scene_bakes_on_the_cluster_its_blurs_after_their_maps(client, tmp_path):
    """A scene whose blur takes its stretch from the stage's bound mesh, on the cluster: each
    blur task starts after its tile's stretch task (here the stretch tasks are slowed: a blur
    that did not wait would find no maps), and the maps, exitance and records are the
    in-process bake's."""
    pytest.importorskip("pxr")
    from stretch_scenes import stretch_scene
    local, cluster = stretch_scene(tmp_path / "local"), stretch_scene(tmp_path / "cluster")
    assert scenes.load(local).plan().run().exit_code == 0

    def slow_maps(job, device=None):
        if job.kind == "stretch":
            time.sleep(3.0)
        return bdask.run_on_worker(job, device)
    report = bdask.bake_on_cluster(scenes.load(cluster).plan(), client, progress=False,
                                   run=slow_maps)
    assert report.exit_code == 0, report.summary()
    for udim in (1001, 1002):
        name = f"skin_sss.{udim}.stretch.exr"
        np.testing.assert_array_equal(read(cluster.parent / "out" / name),
                                      read(local.parent / "out" / name))
        name = f"skin_sss.{udim}.exr"
        np.testing.assert_allclose(read(cluster.parent / "out" / name),
                                   read(local.parent / "out" / name), rtol=1e-6, atol=1e-8)
    for name in ("bdipole.usda", "bdipole_materials.json"):
        a = (local.parent / "out" / name).read_text().replace(str(local.parent), "ROOT")
        b = (cluster.parent / "out" / name).read_text().replace(str(cluster.parent), "ROOT")
        assert a == b, name
    again = bdask.bake_on_cluster(scenes.load(cluster).plan(), client, progress=False)
    assert {r.status for r in again.results} == {"skipped"}
