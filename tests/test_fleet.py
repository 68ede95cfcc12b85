"""`radar-odom fleet`: recordings as Ray tasks on a two-node local cluster, one of them corrupt; what is done is
kept on a second run; every row and output is what `radar-odom run` gives for that recording alone.

The bookkeeping (manifest, names, atomic publication, the missing-extra message) is tested without Ray."""
import csv
import importlib.util
import os
import shutil
import sys

import numpy as np
import pytest

from radar_odom.commands.cli import main
from radar_odom.errors import ConfigError
from radar_odom.fleet.job import process_recording, publish
from radar_odom.fleet.manifest import (
    MANIFEST,
    REPORTS_MANIFEST,
    done_row,
    job_key,
    recording_names,
    write_manifest,
)
from radar_odom.fleet.scheduler import default_threads

FRAMES = 12  # adapt's labelling reads at least 12 sweeps
OUTPUTS = ("estimates.csv", "trajectory.tum", "trajectory.kitti", "ground_truth.tum", "ground_truth.kitti",
           "trajectory.png")
NO_RAY = importlib.util.find_spec("ray") is None


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """Three good simulated drives and one whose sweeps are all garbage (as a corrupt copy would be)."""
    from radar_odom.sim import write_drive

    root = tmp_path_factory.mktemp("fleet-drives")
    good = [write_drive(root / f"drive{s}", seed=s, frames=FRAMES, progress=False) for s in (1, 2, 3)]
    bad = root / "corrupt"
    shutil.copytree(good[0], bad)
    for png in (bad / "radar").glob("*.png"):
        png.write_bytes(b"not a png")
    return [str(p) for p in good], str(bad)


# ------------------------------------------------------------------ bookkeeping, no Ray
def test_a_manifest_vouches_only_for_unchanged_outputs_of_the_same_key(tmp_path):
    folder = tmp_path / "rec"
    folder.mkdir()
    (folder / "estimates.csv").write_text("a,b\n1,2\n")
    write_manifest(folder, "key-1", {"recording": "rec", "sweeps": 2})
    assert done_row(folder, "key-1") == {"recording": "rec", "sweeps": 2}
    assert done_row(folder, "key-2") is None  # other inputs, model or options
    (folder / "estimates.csv").write_text("a,b\n1,3\n")  # same size, other bytes
    assert done_row(folder, "key-1") is None
    (folder / MANIFEST).write_text("{half")
    assert done_row(folder, "key-1") is None
    assert done_row(tmp_path / "never-written", "key-1") is None


def test_the_key_changes_with_an_input_file_the_model_or_an_option(drives):
    good, _ = drives
    key = job_key(good[0], "m1", {"deskew": None})
    assert job_key(good[0], "m1", {"deskew": None}) == key
    assert job_key(good[0], "m2", {"deskew": None}) != key
    assert job_key(good[0], "m1", {"deskew": True}) != key
    ts = next(p for p in os.scandir(os.path.join(good[0], "radar")))
    st = os.stat(ts.path)
    os.utime(ts.path, ns=(st.st_atime_ns, st.st_mtime_ns + 1000))
    try:
        assert job_key(good[0], "m1", {"deskew": None}) != key
    finally:
        os.utime(ts.path, ns=(st.st_atime_ns, st.st_mtime_ns))


def test_recordings_sharing_a_name_get_their_parent_in_it_and_one_given_twice_is_refused(tmp_path):
    a, b = tmp_path / "car1" / "2019-01-10", tmp_path / "car2" / "2019-01-10"
    assert recording_names([a, b, tmp_path / "x"]) == ["car1-2019-01-10", "car2-2019-01-10", "x"]
    with pytest.raises(ConfigError, match="both write to"):
        recording_names([a, a])


def test_publish_replaces_fleets_own_earlier_folder_whole(tmp_path):
    old, new = tmp_path / "rec", tmp_path / ".rec.tmp"
    row = {"recording": "rec", "path": str(tmp_path / "drives" / "rec")}
    old.mkdir()
    (old / "stale.csv").write_text("old")
    write_manifest(old, "key-1", row)  # fleet's own earlier outputs of that recording (tests/test_outputs_kept.py:
    new.mkdir()                        # a folder holding anything else is refused)
    (new / "estimates.csv").write_text("new")
    write_manifest(new, "key-2", row)
    publish(new, old)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]
    assert sorted(p.name for p in old.iterdir()) == ["estimates.csv", MANIFEST]


def test_a_failing_recording_leaves_nothing_behind(drives, cli_model, tmp_path):
    _, bad = drives
    (tmp_path / ".corrupt.tmp-0dead0").mkdir()  # an attempt killed with its worker
    with pytest.raises(Exception, match="none of its"):
        process_recording(str(cli_model), bad, tmp_path, "corrupt", {"plot": False}, "k")
    assert list(tmp_path.iterdir()) == []


def test_threads_per_recording_share_the_cpus_among_few_recordings_and_are_one_for_many():
    assert default_threads([2.0, 2.0], 8) == 1
    assert default_threads([8.0, 8.0], 2) == 8
    assert default_threads([4.0], 3) == 1
    assert default_threads([16.0, 2.0], 1) == 2  # at most the smallest node's CPUs


def test_without_ray_fleet_says_in_one_line_how_to_install_it(drives, monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    assert main(["fleet", drives[0][0], "-o", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'pip install "radar-odom[fleet]"' in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(NO_RAY, reason='the fleet extra (Ray) is not installed: pip install -e ".[fleet]"')
def test_a_model_no_worker_could_load_is_one_error_before_anything_starts(drives, tmp_path, capsys):
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not onnx")
    assert main(["fleet", drives[0][0], "-o", str(tmp_path / "out"), "--model", str(junk)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cannot load this model" in err, err
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------ on a two-node Ray cluster
@pytest.fixture(scope="module")
def cluster():
    if NO_RAY:
        pytest.skip('the fleet extra (Ray) is not installed: pip install -e ".[fleet]"')
    from ray.cluster_utils import Cluster

    c = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    c.add_node(num_cpus=1)  # a second node process: one slot each, so the two workers sit on two nodes
    c.wait_for_nodes()
    yield c
    c.shutdown()


def _rows(out):
    with open(out / "fleet.csv", newline="") as f:
        return {r["recording"]: r for r in csv.DictReader(f)}


@pytest.mark.slow
def test_a_fleet_on_two_nodes_completes_the_good_reports_the_bad_and_resumes(drives, cluster, cli_model, tmp_path,
                                                                            capsys):
    from radar_odom.evaluation.metrics import path_lengths_m
    from radar_odom.evaluation.trajectory import read_tum

    good, bad = drives
    out = tmp_path / "OUT"
    fleet = ["fleet", *good, bad, "-o", str(out), "--address", cluster.address, "--model", str(cli_model),
             "--no-progress"]
    assert main(fleet) == 1  # one recording failed
    printed = capsys.readouterr()
    assert "3 done, 0 kept" in printed.out and "1 failed" in printed.out
    assert "on 2 worker(s), 2 node(s)" in printed.out
    assert f"failed {bad} (after 2 attempts): " in printed.err and "none of its" in printed.err
    rows = _rows(out)
    assert rows["corrupt"]["status"] == "failed" and rows["corrupt"]["attempts"] == "2"
    assert f"none of its {FRAMES} sweeps could be used" in rows["corrupt"]["reason"]
    # no temporary folder left; the one hidden file is the reports' manifest (tests/test_outputs_kept.py)
    assert not (out / "corrupt").exists()
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == [REPORTS_MANIFEST]
    assert (out / "fleet.md").is_file() and "corrupt" in (out / "fleet.md").read_text()

    for drive in good:  # each recording on its own, as a user would run it: the same files, the same figures
        name = os.path.basename(drive)
        alone = tmp_path / f"run-{name}"
        assert main(["run", drive, "--model", str(cli_model), "-o", str(alone), "--threads", "1"]) == 0
        said = capsys.readouterr().out
        for f in OUTPUTS:
            assert (out / name / f).read_bytes() == (alone / f).read_bytes(), f"{name}/{f}"
        r = rows[name]
        assert r["status"] == "done"
        assert (f"{r['sweeps']} sweeps, {r['estimates']} estimates ({r['degenerate']} degenerate; {r['gated']} "
                f"gated, {r['prior_dominated']} prior-dominated)") in said
        assert (f"mean_translation_m {float(r['step_translation_m']):.4g}, "
                f"mean_rotation_deg {float(r['step_rotation_deg']):.4g}") in said
        ts, poses = read_tum(alone / "trajectory.tum")
        assert float(r["duration_s"]) == (ts[-1] - ts[0]) * 1e-6
        assert np.isclose(float(r["length_m"]), path_lengths_m(poses)[-1], rtol=1e-12, atol=0)

    # the same command again: the done recordings are kept untouched, except one whose output was edited
    kept = out / os.path.basename(good[0]) / "estimates.csv"
    mtime = kept.stat().st_mtime_ns
    edited = out / os.path.basename(good[1]) / "trajectory.tum"
    edited.write_text(edited.read_text() + "\n")
    assert main(fleet) == 1
    assert "1 done, 2 kept" in capsys.readouterr().out
    rows = _rows(out)
    assert [rows[os.path.basename(g)]["status"] for g in good] == ["kept", "done", "kept"]
    assert kept.stat().st_mtime_ns == mtime
    assert edited.read_bytes() == (tmp_path / f"run-{os.path.basename(good[1])}" / "trajectory.tum").read_bytes()


@pytest.mark.slow
def test_adapt_labels_on_ray_workers_are_each_recordings_own_runtime_chain(drives, cluster, cli_model):
    from radar_odom_export.adapt import read_recording, run_runtime
    from radar_odom_export.adapt_labels import ray_labeller

    good, _ = drives
    got = ray_labeller(cluster.address, threads=1)(cli_model, good[:2], None, slice(None))
    assert len(got) == 2
    for source, (poses, rel) in zip(good[:2], got):
        want_poses, want_rel = run_runtime(cli_model, read_recording(source).scans, 1)
        assert np.array_equal(poses, want_poses) and np.array_equal(rel, want_rel, equal_nan=True)


def test_the_report_ranks_kitti_percent_and_per_step_metres_in_tables_of_their_own(tmp_path):
    """Issue 51: fleet.md's "Worst drives" mixed % and m per step in one column. Each unit gets its own table
    and header; no row carries a unit of its own."""
    from radar_odom.fleet.report import COLUMNS, DONE, write_summary

    def row(name, **values):
        return {**dict.fromkeys(COLUMNS, ""), "recording": name, "status": DONE, "sweeps": "10", "duration_s": "2.5",
                "length_m": "20", "mean_speed_m_s": "8", **values}

    rows = [row("long-a", translation_percent="3.5"), row("long-b", translation_percent="7.25"),
            row("short-a", step_translation_m="0.125")]
    text = write_summary(tmp_path, rows).read_text()
    kitti, short = text.split("## Worst drives")[1].split("## Worst short drives")
    assert "| recording | KITTI translation % |" in kitti and "| recording | mean step error m |" in short
    assert kitti.index("long-b") < kitti.index("long-a") and "short-a" not in kitti
    assert "short-a" in short and "long-a" not in short
    assert "m per step" not in text and " %" not in text.split("## Worst drives")[1].replace("translation %", "")
