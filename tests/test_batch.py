"""`hybrid batch`: jobs of scenes x cameras x AOVs into a folder. A failing item is reported and the rest finish; a
killed batch resumes without rendering finished items again and leaves no partial file; two workers write the same
files as one; the Ray path runs end to end on a local cluster that the test starts (on loopback)."""

import importlib.util
import json
import os
import re
import secrets
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

try:
    import tomllib
except ModuleNotFoundError:
    import tomli as tomllib

from engine.batch import MANIFEST_NAME, load_job, run_batch
from engine.batch.job import job_from_dict
from engine.batch.manifest import LOCK_NAME
from engine.errors import ConfigError

REPO = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, PYTHONPATH=str(REPO), HYBRID_VALIDATION="1", RAY_USAGE_STATS_ENABLED="0")


def write_job(folder: Path, text: str, name: str = "job.toml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


def hybrid_batch(*args, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "engine", "batch", *map(str, args)],
        cwd=cwd,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def manifest(out: Path) -> dict:
    return json.loads((out / MANIFEST_NAME).read_text())


def npz(path: Path) -> dict:
    with np.load(path) as data:
        return {k: data[k] for k in data.files}


def outputs(out: Path) -> dict:
    """Every output file's content: .npz as their arrays, PNGs as their pixels."""
    got = {}
    for p in sorted(out.rglob("*")):
        if p.suffix == ".npz":
            got[str(p.relative_to(out))] = npz(p)
        elif p.suffix == ".png":
            got[str(p.relative_to(out))] = np.asarray(Image.open(p))
    return got


def assert_same_outputs(a: Path, b: Path):
    got_a, got_b = outputs(a), outputs(b)
    assert sorted(got_a) == sorted(got_b)
    for name, va in got_a.items():
        vb = got_b[name]
        if isinstance(va, dict):
            assert sorted(va) == sorted(vb), name
            for k in va:
                assert np.array_equal(va[k], vb[k]), f"{name}: {k} differs"
        else:
            assert np.array_equal(va, vb), f"{name} differs"


def no_temporaries(out: Path) -> list[str]:
    return [str(p) for p in out.rglob("*") if p.name.endswith(".tmp") or ".part-" in p.name]


# ---- failures ------------------------------------------------------------------------------------------------------
FAILING_JOB = """
output = "out"
size = "64x48"
aovs = ["color", "depth", "object_id"]
png = ["color", "depth"]

[cameras]
orbit = 2

[[scenes]]
scene = "sphere"

[[scenes]]
scene = "missing.toml"

[[scenes]]
scene = "sphere"
name = "views"
[[scenes.cameras.views]]
eye = [0, 0, 4]
target = [0, 0, 0]
[[scenes.cameras.views]]
pose = [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]
[[scenes.cameras.views]]
K = [[60, 0, 32], [0, 60, 24], [0, 0, 1]]
width = 64
height = 32
[[scenes.cameras.views]]
eye = [0, 3, 1]
target = [0, 0, 0]
fov = 50
"""


def test_a_job_with_failing_items_finishes_the_rest_and_reports_them(tmp_path):
    job = write_job(tmp_path, FAILING_JOB)
    res = hybrid_batch(job, "-q", cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    out = tmp_path / "out"
    m = manifest(out)
    status = {k: v["status"] for k, v in m["items"].items()}
    assert status == {
        "sphere/0000": "done",
        "sphere/0001": "done",
        "missing/0000": "failed",
        "missing/0001": "failed",
        "views/0000": "done",
        "views/0001": "failed",
        "views/0002": "failed",
        "views/0003": "done",
    }
    assert m["counts"] == {"items": 8, "done": 4, "failed": 4, "todo": 0}
    errors = {k: v.get("error", "") for k, v in m["items"].items()}
    assert errors["missing/0000"].startswith(f"{tmp_path / 'missing.toml'}: ")  # the loader's error, naming it
    assert re.search(r"job\.toml: scenes\[2\]\.cameras\.views\[1\]: camera pose must be rigid", errors["views/0001"])
    assert re.search(
        r"scenes\[2\]\.cameras\.views\[2\]: camera: its intrinsics are for a 64x32 image", errors["views/0002"]
    )
    # one line per failure on stderr, and the summary on stdout
    failed_lines = [ln for ln in res.stderr.splitlines() if ln.startswith("failed: ")]
    assert len(failed_lines) == 4 and all("Traceback" not in ln for ln in res.stderr.splitlines())
    assert "8 items of job.toml: 4 rendered, 0 already done, 4 failed" in res.stdout
    # what finished is complete: the pixels of the sphere, its depth, its id; nothing of the failed items
    for item in ("sphere/0000", "sphere/0001", "views/0000", "views/0003"):
        arrays = npz(out / f"{item}.npz")
        covered = np.isfinite(arrays["depth"])
        assert 0.05 < covered.mean() < 0.9
        assert np.array_equal(arrays["object_id"] >= 0, covered)
        assert str(arrays["key"]) == m["items"][item]["key"] and str(arrays["object_names"][0]) == "sphere"
        assert Image.open(out / f"{item}.png").size == (64, 48)
        assert Image.open(out / f"{item}.depth.png").size == (64, 48)
    assert not (out / "missing").exists() and not list(out.glob("views/0001*"))
    # run again: the finished items are skipped, the failed ones are tried again (and fail again)
    again = hybrid_batch(job, "-q", cwd=tmp_path)
    assert again.returncode == 1
    assert "8 items of job.toml: 0 rendered, 4 already done, 4 failed" in again.stdout


BAD_JOBS = [
    ("size = '64x48'\n[cameras]\norbit = 2\n[[scenes]]\nscene = 'sphere'\n", r"output: give the output folder"),
    ("output = 'o'\nscenez = 1\n", r"unknown key 'scenez'"),
    ("output = 'o'\naovs = ['colour']\n[cameras]\norbit = 1\n[[scenes]]\nscene = 'sphere'\n", r"aov 'colour'"),
    (
        "output = 'o'\naovs = ['depth']\npng = ['color']\n[cameras]\norbit = 1\n[[scenes]]\nscene = 'sphere'\n",
        r"png: 'color' is not among the aovs",
    ),
    ("output = 'o'\nsize = '64x'\n[cameras]\norbit = 1\n[[scenes]]\nscene = 'sphere'\n", r"size '64x'"),
    (
        "output = 'o'\n[settings]\nshadows = 'fuzzy'\n[cameras]\norbit = 1\n[[scenes]]\nscene = 'sphere'\n",
        r"setting shadows='fuzzy'",
    ),
    ("output = 'o'\n[cameras]\norbit = 0\n[[scenes]]\nscene = 'sphere'\n", r"cameras\.orbit: expected the number"),
    (
        "output = 'o'\n[cameras]\norbit = 2\nviews = []\n[[scenes]]\nscene = 'sphere'\n",
        r"cameras: give exactly one of .*found both orbit and views",
    ),
    (
        "output = 'o'\n[cameras]\npath = 'nope.json'\n[[scenes]]\nscene = 'sphere'\n",
        r"nope\.json: no such camera-path file",
    ),
    (
        "output = 'o'\n[cameras]\norbit = 1\n[[scenes]]\nscene = 'sphere'\n[[scenes]]\nscene = 'sphere'\n",
        r"scenes\[1\]: name 'sphere' is scenes\[0\]'s too",
    ),
    ("output = 'o'\n[[scenes]]\nscene = 'sphere'\n", r"scenes\[0\]: no cameras"),
    ("output = 'o'\nframes = 0\n[cameras]\norbit = 1\n[[scenes]]\nscene = 'sphere'\n", r"frames: expected"),
    ("output = 'o'\n[cameras]\norbit = 1\n[[scenes]]\nscene = 'a b.obj'\n", r"name 'a b': the output folder"),
    ("output = 'o'\n[cameras\n", r"not valid TOML"),
]


@pytest.mark.parametrize("text,message", BAD_JOBS, ids=[m for _, m in BAD_JOBS])
def test_a_bad_job_file_is_a_clear_error(tmp_path, text, message):
    job = write_job(tmp_path, text)
    with pytest.raises(ConfigError, match=message) as info:
        load_job(job)
    assert str(info.value).startswith(str(job)) and "\n" not in str(info.value)


def test_a_bad_job_is_one_line_on_the_command_line(tmp_path):
    job = write_job(tmp_path, BAD_JOBS[1][0])
    res = hybrid_batch(job, cwd=tmp_path)
    assert res.returncode == 1 and res.stdout == ""
    assert (
        res.stderr == f"error: {job}: unknown key 'scenez' (known: output, size, aovs, png, frames, compress, "
        "settings, cameras, scenes, labels)\n"
    )


@pytest.mark.parametrize(
    "args,message",
    [
        (["--workers", "0"], "--workers 0: expected 1..64"),
        (["--devices", "7"], "--devices: device='7': no such device index"),
        (["--devices", "0,,1"], "--devices '0,,1': expected device indices or names separated by commas"),
        (
            ["--ray", "local", "--workers", "2"],
            "--ray runs the items as Ray tasks: --workers and --devices do not apply",
        ),
        (["--shard-size", "0"], "--shard-size 0: expected a positive number of items"),
        (["--ray", "127.0.0.1:1"], "--ray 127.0.0.1:1: no Ray cluster answers there"),  # not a minutes-long retry
    ],
)
def test_bad_options_are_one_line_errors(tmp_path, args, message):
    job = write_job(tmp_path, "output = 'out'\nsize = '32x24'\n[cameras]\norbit = 1\n[[scenes]]\nscene = 'sphere'\n")
    res = hybrid_batch(job, *args, cwd=tmp_path)
    assert res.returncode == 1 and res.stderr.startswith(f"error: {message}") and res.stderr.count("\n") == 1
    assert not (tmp_path / "out" / "sphere").exists()


def test_a_second_batch_on_the_same_folder_is_refused(tmp_path):
    job = load_job(
        write_job(tmp_path, "output = 'out'\nsize = '32x24'\n[cameras]\norbit = 1\n[[scenes]]\nscene = 'sphere'\n")
    )
    job.output.mkdir()
    (job.output / LOCK_NAME).write_text(json.dumps({"host": os.uname().nodename, "pid": os.getpid()}))
    with pytest.raises(ConfigError, match=r"another batch is writing here \(pid \d+"):
        run_batch(job, progress=False)
    (job.output / LOCK_NAME).write_text(json.dumps({"host": os.uname().nodename, "pid": 2**22 + 7}))  # gone
    result = run_batch(job, progress=False)
    assert result.ok and result.rendered == 1 and not (job.output / LOCK_NAME).exists()


def test_items_are_rendered_again_when_what_they_depend_on_changes(tmp_path):
    text = (
        "output = 'out'\nsize = '32x24'\naovs = ['color', 'depth']\n[settings]\nao_samples = 1\n"
        "[cameras]\norbit = 3\n[[scenes]]\nscene = 'sphere'\n"
    )
    path = write_job(tmp_path, text)
    first = run_batch(load_job(path), progress=False)
    assert (first.rendered, first.skipped) == (3, 0)
    assert (run_batch(load_job(path), progress=False).rendered, first.ok) == (0, True)
    # a killed batch's temporaries go with the next run, though it writes none of those files (issue #36)
    for name in ("sphere/.0000.npz.part-999999-abc.tmp", ".manifest.json.part-999999-abc.tmp"):
        (tmp_path / "out" / name).write_bytes(b"partial")
        os.utime(tmp_path / "out" / name, (time.time() - 60,) * 2)
    assert run_batch(load_job(path), progress=False).skipped == 3
    assert no_temporaries(tmp_path / "out") == []
    # another setting: every key changes; the manifest is not needed to tell (the .npz holds its item's key)
    (tmp_path / "out" / MANIFEST_NAME).unlink()
    assert run_batch(load_job(path), progress=False).skipped == 3
    write_job(tmp_path, text.replace("ao_samples = 1", "ao_samples = 2"))
    changed = run_batch(load_job(path), progress=False)
    assert (changed.rendered, changed.skipped) == (3, 0)
    assert run_batch(load_job(path), progress=False, redo=True).rendered == 3


def test_a_scene_files_own_settings_are_part_of_its_items_keys(tmp_path):
    """The settings in effect are the job's over the scene file's [settings]: a rerun after the scene's settings
    changed renders its items again (issue #36: they were skipped, the files holding the old settings)."""
    scene = tmp_path / "s.toml"
    scene.write_text((REPO / "scenes" / "sphere.toml").read_text())
    text = "output = 'out'\nsize = '16x12'\naovs = ['depth']\n[cameras]\norbit = 1\n[[scenes]]\nscene = 's.toml'\n"
    path = write_job(tmp_path, text)
    plain = load_job(path).items[0].key
    assert run_batch(load_job(path), progress=False).rendered == 1
    scene.write_text(scene.read_text() + "\n[settings]\nshadows = 'off'\n")
    assert load_job(path).items[0].key != plain
    assert run_batch(load_job(path), progress=False).rendered == 1
    assert run_batch(load_job(path), progress=False).skipped == 1
    scene.write_text((REPO / "scenes" / "sphere.toml").read_text())
    assert load_job(path).items[0].key == plain  # no [settings]: the key is what it was before scene settings counted


# ---- kill and resume -----------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_a_killed_batch_resumes_without_redoing_finished_items(tmp_path):
    n = 24
    job = write_job(
        tmp_path,
        f"output = 'out'\nsize = '96x72'\nframes = 2\naovs = ['color', 'depth', 'normal']\n"
        f"[cameras]\norbit = {n}\n[[scenes]]\nscene = 'default'\n",
    )
    out = tmp_path / "out" / "default"
    proc = subprocess.Popen(
        [sys.executable, "-m", "engine", "batch", str(job), "-q", "--shard-size", "4"],
        cwd=tmp_path,
        env=ENV,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 240
        while len(list(out.glob("*.npz"))) < 3:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the batch rendered nothing in 240 s"
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
    done = sorted(out.glob("*.npz"))
    assert 3 <= len(done) < n, "killed after the end: nothing to resume"
    # every file there is whole: the .npz load with their key, the PNGs decode
    before = {}
    for p in done:
        arrays = npz(p)
        assert arrays["depth"].shape == (72, 96) and len(str(arrays["key"])) == 24
        before[p.name] = (p.stat().st_ino, p.stat().st_mtime_ns)
    for p in out.glob("*.png"):
        Image.open(p).load()
    res = hybrid_batch(job, "-q", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    m = re.search(r"(\d+) rendered, (\d+) already done, 0 failed", res.stdout)
    assert m and int(m.group(1)) + int(m.group(2)) == n and int(m.group(2)) >= len(done), res.stdout
    for p in done:  # not written again
        assert (p.stat().st_ino, p.stat().st_mtime_ns) == before[p.name]
    assert len(list(out.glob("*.npz"))) == n and len(list(out.glob("*.png"))) == n
    assert manifest(tmp_path / "out")["counts"] == {"items": n, "done": n, "failed": 0, "todo": 0}
    assert no_temporaries(tmp_path / "out") == []
    assert not (tmp_path / "out" / LOCK_NAME).exists()


# ---- workers -------------------------------------------------------------------------------------------------------
PARALLEL_JOB = """
output = "out"
size = "64x48"
frames = 2
aovs = ["color", "depth", "shadow", "ao", "history", "object_id", "motion"]
png = ["color", "object_id"]

[settings]
shadows = "soft"
ao_samples = 2

[cameras]
orbit = 3

[[scenes]]
scene = "default"

[[scenes]]
scene = "penumbra"
"""


@pytest.mark.slow
def test_two_workers_write_the_same_files_as_one(tmp_path):
    """Soft shadows and AO accumulated over 2 frames per view: each view starts afresh, so the items' split over
    the workers (shards of one item, taken in turn) changes no pixel."""
    job = write_job(tmp_path, PARALLEL_JOB)
    one = hybrid_batch(job, "-q", "-o", tmp_path / "one", cwd=tmp_path)
    assert one.returncode == 0, one.stderr
    two = hybrid_batch(job, "-q", "-o", tmp_path / "two", "--workers", "2", "--shard-size", "1", cwd=tmp_path)
    assert two.returncode == 0, two.stderr
    assert "6 items of job.toml: 6 rendered, 0 already done, 0 failed" in two.stdout and "on 2 workers" in two.stdout
    workers = {rec["worker"] for rec in manifest(tmp_path / "two")["items"].values()}
    assert len(workers) == 2 and {w.split("@")[0] for w in workers} == {"worker 0", "worker 1"}
    assert_same_outputs(tmp_path / "one", tmp_path / "two")
    history = npz(tmp_path / "two" / "penumbra" / "0002.npz")["history"]
    assert history.max() == 2  # the view's two frames accumulated, nothing from the view before


def test_the_example_job_runs(tmp_path):
    """examples/batch_job.toml (at a smaller size of the same aspect): every item done, the views' files there."""
    path = REPO / "examples" / "batch_job.toml"
    data = tomllib.loads(path.read_text())
    data["size"] = "64x48"
    job = job_from_dict(data, path, tmp_path / "out")
    result = run_batch(job, progress=False)
    assert result.ok and result.rendered == len(job.items) == 6 + 6 + 2 + 3, result.failed
    for item in job.items:
        assert all((job.output / f).is_file() for f in job.files(item))


def test_the_jobs_in_the_docs_load(tmp_path):
    blocks = re.findall(r"```toml\n(.*?)```", (REPO / "docs" / "batch.md").read_text(), flags=re.S)
    jobs = [b for b in blocks if "[[scenes]]" in b]
    assert jobs
    for text in jobs:
        job = job_from_dict(tomllib.loads(text), tmp_path / "job.toml")
        assert job.items


# ---- Ray -----------------------------------------------------------------------------------------------------------
RAY_HEAD = r"""
import sys
import ray
ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
print(ray.get_runtime_context().gcs_address, ray.util.get_node_ip_address(), flush=True)
sys.stdin.read()   # until the test closes stdin
ray.shutdown()
"""


@pytest.mark.skipif(
    importlib.util.find_spec("ray") is None,
    reason="Ray is not installed (pip install '.[distributed]' or pip install ray)",
)
@pytest.mark.slow
def test_ray_runs_a_job_end_to_end_on_a_local_cluster(tmp_path):
    """A 2-CPU Ray cluster on loopback, started here; `hybrid batch --ray ADDRESS` submits shards as tasks, which
    write the files; the driver merges the manifest. The files equal a local run's; a failing item is reported."""
    job = write_job(
        tmp_path,
        "output = 'out'\nsize = '64x48'\naovs = ['color', 'depth', 'object_id']\n"
        "[cameras]\norbit = 3\n[[scenes]]\nscene = 'sphere'\n[[scenes]]\nscene = 'default'\n"
        "[[scenes]]\nscene = 'missing.obj'\n",
    )
    # A single-machine cluster (loopback only), with token authentication (the token in the environment, not in
    # ~/.ray): the head and the driver share it.
    env = dict(ENV, RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0", RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(16))
    head = subprocess.Popen(
        [sys.executable, "-c", RAY_HEAD],
        cwd=tmp_path,
        env=env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        line = head.stdout.readline().split()
        assert len(line) == 2, "the Ray head did not start"
        address, node = line
        assert address.startswith("127.0.0.1:") and node == "127.0.0.1"
        res = subprocess.run(
            [sys.executable, "-m", "engine", "batch", str(job), "-q", "--ray", address, "--shard-size", "2"],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=180,
        )
    finally:
        head.stdin.close()
        try:
            head.wait(timeout=60)
        except subprocess.TimeoutExpired:
            head.kill()
            head.wait()
    assert res.returncode == 1, res.stderr[-3000:]
    assert "9 items of job.toml: 6 rendered, 0 already done, 3 failed" in res.stdout
    assert f"Ray at {address}: 2 CPUs, 6 tasks" in res.stdout
    m = manifest(tmp_path / "out")
    assert m["counts"] == {"items": 9, "done": 6, "failed": 3, "todo": 0}
    assert all(rec["worker"].startswith("ray 127.0.0.1@") for rec in m["items"].values())
    assert all("missing.obj" in m["items"][f"missing/{i:04d}"]["error"] for i in range(3))
    # the same files as one local worker
    local = run_batch(load_job(job, tmp_path / "local"), progress=False)
    assert local.rendered == 6
    (tmp_path / "out" / MANIFEST_NAME).unlink()
    (tmp_path / "local" / MANIFEST_NAME).unlink()
    assert_same_outputs(tmp_path / "out", tmp_path / "local")


def test_the_summary_line_escapes_names_and_paths(tmp_path):
    from engine.batch.driver import BatchResult

    text = "output = 'o'\nsize = '16x12'\n[cameras]\norbit = 1\n[[scenes]]\nscene = 'sphere'\n"
    job = load_job(write_job(tmp_path, text, name="j\n\x1b[2J.toml"))
    line = BatchResult(manifest=str(tmp_path / "o\n" / MANIFEST_NAME), where="nothing to render").summary(job)
    assert "\n" not in line and "\x1b" not in line and "j\\n\\x1b[2J.toml" in line and "o\\n/manifest.json" in line
