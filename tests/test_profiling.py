"""`radar-odom profile`: statistics, the onnxruntime trace parser, the numpy-FFT reference
against the rotation maths and the torch model, the report, and a short end-to-end run."""
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from radar_odom.latency import markdown_report
from radar_odom.latency.reference import FFTReference, _rotation_matrix, state_to_image, state_to_spectrum
from radar_odom.latency.stats import latency_summary, operator_profile
from radar_odom.profiles import GridProfile


def small_profile(**kw):
    base = dict(resolution_m=1.0, width_px=64, max_translation_m=6.0, rotation_range_rad=math.radians(6),
                rotation_step_rad=math.radians(1), beta_pose=20.0, beta_cov=20.0, near_range_m=0.0)
    base.update(kw)
    return GridProfile("small", **base)


def blob_pair(pose, width=64, res=1.0, count=25, seed=0, sigma=2.0):
    """Static blobs seen from two frames; ``pose`` is the current frame in the previous (Oxford)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-0.3 * width * res, 0.3 * width * res, size=(count, 2))
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    rel = pts - np.array([x, y])
    cur = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=1)

    def render(points):
        cw = (width - 1) / 2
        xs = ((cw - np.arange(width)) * res)[:, None]
        ys = ((np.arange(width) - cw) * res)[None, :]
        img = sum(np.exp(-((xs - px) ** 2 + (ys - py) ** 2) / (2 * sigma**2)) for px, py in points)
        return img.astype(np.float32)

    return render(pts), render(cur)


def test_latency_summary_by_hand():
    s = latency_summary([0.001, 0.002, 0.003, 0.004])
    assert s["median"] == pytest.approx(2.5) and s["mean"] == pytest.approx(2.5) and s["min"] == pytest.approx(1.0)
    assert s["p90"] == pytest.approx(3.7) and s["n"] == 4
    assert latency_summary([])["median"] is None


def test_operator_profile_groups_node_times_per_run(tmp_path):
    def node(name, op, ts, dur):
        return {"cat": "Node", "name": f"{name}_kernel_time", "ts": ts, "dur": dur, "args": {"op_name": op}}

    events = [
        {"cat": "Session", "name": "model_run", "ts": 0, "dur": 1000},
        node("conv1", "Conv", 10, 300), node("conv2", "Conv", 400, 100), node("mm", "MatMul", 600, 200),
        {"cat": "Session", "name": "model_run", "ts": 2000, "dur": 1000},
        node("conv1", "Conv", 2010, 500), node("conv2", "Conv", 2600, 100), node("mm", "MatMul", 2800, 100),
        node("outside", "Relu", 5000, 999),  # in no run: ignored
        {"cat": "Node", "name": "mm_fence_before", "ts": 2800, "dur": 0, "args": {"op_name": "MatMul"}},
    ]
    path = tmp_path / "trace.json"
    path.write_text(json.dumps(events))
    ops = operator_profile(path)
    assert list(ops) == ["Conv", "MatMul"]  # by time, descending; Relu ran outside every run
    assert ops["Conv"]["median"] == pytest.approx(0.5) and ops["Conv"]["nodes"] == 2  # runs: 0.4, 0.6 ms
    assert ops["MatMul"]["median"] == pytest.approx(0.15)
    assert ops["Conv"]["share"] + ops["MatMul"]["share"] == pytest.approx(1.0)
    assert ops["Conv"]["share"] == pytest.approx(1.0 / 1.3)


def test_masker_time_sums_the_unet_operator_classes_per_run():
    from radar_odom.latency.stats import masker_time

    per_run = {"FusedConv": np.array([0.002, 0.004]), "MaxPool": np.array([0.001, 0.001]),
               "MatMul": np.array([0.010, 0.020])}
    s = masker_time(per_run)
    assert s["median"] == pytest.approx(4.0) and s["n"] == 2  # runs: 3 ms and 5 ms


def test_reference_rotation_follows_the_graph_convention():
    """warpAffine with the reference's matrix samples S(Rᵀq): a target at p appears at R·p."""
    import cv2

    width, yaw = 64, math.radians(10)
    img, _ = blob_pair((0, 0, 0), count=1, seed=4)
    out = cv2.warpAffine(img, _rotation_matrix(yaw, width), (width, width),
                         flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderValue=0.0)
    cw = (width - 1) / 2
    xs, ys = (cw - np.arange(width))[:, None], (np.arange(width) - cw)[None, :]

    def centroid(a):
        w = a * (a > 0.2)
        return np.array([(w * xs).sum() / w.sum(), (w * ys).sum() / w.sum()])

    p = centroid(img)
    want = np.array([math.cos(yaw) * p[0] - math.sin(yaw) * p[1], math.sin(yaw) * p[0] + math.cos(yaw) * p[1]])
    assert np.abs(centroid(out) - want).max() < 0.1


@pytest.mark.parametrize("pose", [(3.0, -2.0, math.radians(4)), (-1.0, 4.0, math.radians(-4))])
def test_reference_search_recovers_a_known_pose(pose):
    profile = small_profile(width_px=128)
    prev, cur = blob_pair(pose, width=128)
    ref = FFTReference(profile)
    got, cov = ref.search(np.fft.rfft2(prev), cur)
    assert abs(got[0] - pose[0]) < 0.3 and abs(got[1] - pose[1]) < 0.3
    assert abs(got[2] - pose[2]) < math.radians(0.6)
    assert np.all(np.linalg.eigvalsh(cov) > -1e-9)
    # the coarse-to-fine variant (the fast graph's search: a 64 px coarse stage, 3 yaws) agrees
    fast = FFTReference(profile, {"coarse_factor": 2, "coarse_stride": 2, "band_rotations": 3})
    true_index = int(round(math.degrees(pose[2]))) + 6
    assert true_index in fast.band(np.fft.rfft2(prev), np.fft.rfft2(cur))
    assert np.allclose(fast.search(np.fft.rfft2(prev), cur)[0], got, atol=0.05)


@pytest.mark.torch
def test_reference_equals_the_torch_exhaustive_step():
    torch = pytest.importorskip("torch")
    from radar_odom_export.model import MaskedCorrelator

    profile = small_profile(beta_pose=1.0, beta_cov=0.5)
    model = MaskedCorrelator(profile, masking="raw").eval()
    prev, cur = blob_pair((2.0, 1.0, math.radians(3)), seed=2)
    with torch.no_grad():
        state = model.initial_state(torch.from_numpy(prev)[None])
        pose, cov, new_state = model.stream_step(torch.from_numpy(cur)[None], state)
    s_cur = state_to_image(new_state.numpy(), 64)  # the masked image, recovered from the state
    got, got_cov = FFTReference(profile).search(state_to_spectrum(state.numpy()), s_cur)
    # OpenCV interpolates at 1/32 px, grid_sample exactly: equal to a small fraction of a cell
    assert np.abs(got - pose[0].numpy()).max() < 0.02
    assert np.abs(got_cov - cov[0].numpy()).max() < 0.05 * np.abs(cov[0].numpy()).max()


def fake_report():
    stages = {s: {"median": m, "p90": m + 1, "p99": m + 2, "mean": m, "min": m, "n": 200}
              for s, m in (("png_decode", 9.0), ("sweep_parse", 2.0), ("polar_to_cartesian", 1.0),
                           ("graph", 8.0), ("step", 9.0), ("full", 20.0))}
    return {
        "command": "radar-odom profile",
        "machine": {
            "cpu": "Test CPU",
            "logical_cores": 2,
            "physical_cores": 2,
            "onnxruntime": "1.0",
            "numpy": "2.0",
            "python": "3.11",
            "threads": 2,
            "load_average": [0.5, 0.5, 0.5],
        },
        "settings": {
            "steps": 200,
            "warmup": 20,
            "threads": 2,
            "reference_steps": 30,
            "operator_steps": 50,
            "distinct_sweeps": 24,
            "sweeps": "simulated",
        },
        "models": [
            {
                "name": "cart-0.4",
                "path": "m.onnx",
                "untrained": True,
                "profile": {
                    "name": "cart-0.4",
                    "resolution_m": 0.4,
                    "width_px": 256,
                    "rotation_range_rad": math.pi / 12,
                    "rotation_step_rad": math.pi / 360,
                },
                "search": {"coarse_factor": 4, "coarse_stride": 2, "band_rotations": 3, "rotation": "polar"},
                "stages": stages,
                "peak_rss_mb": 123.0,
                "masker": {"median": 3.0},
                "operators": {
                    "MatMul": {"median": 4.0, "p90": 5.0, "p99": 6.0, "mean": 4.0, "share": 0.6, "nodes": 12}
                },
                "reference": {
                    "exhaustive": {
                        "time": {"median": 80.0},
                        "pose_diff_median": {"x_m": 0.01, "y_m": 0.0, "yaw_rad": 0.001},
                    },
                    "same_search": {
                        "time": {"median": 10.0},
                        "pose_diff_median": {"x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0},
                    },
                },
            }
        ],
        "rss_stream": {
            "model": "cart-0.4",
            "steps": 1000,
            "every": 50,
            "samples": [[1, 100.0], [50, 110.0], [1000, 111.0]],
            "peak_mb": 112.0,
            "growth_mb": 1.0,
            "growth_from_step": 100,
        },
    }


def test_markdown_report_holds_the_measured_numbers():
    md = markdown_report(fake_report())
    assert "Machine: Test CPU, 2 logical / 2 physical cores, onnxruntime 1.0" in md
    row = next(line for line in md.splitlines() if line.startswith("| cart-0.4 |"))
    assert "| 8.0 / 9.0 / 10.0 |" in row and "| 9.0 / 10.0 / 11.0 |" in row  # graph, step
    assert "| 16.9 |" in row  # the paper's GPU time for 0.4 m/px
    assert "0.10 (80.0 ms)" in row and "0.80 (10.0 ms)" in row  # graph / reference ratios
    assert "| 0.50 (5.0 ms) |" in row  # (graph − masker) / same-search reference
    assert "band 3 yaws" in row and "| 123 |" in row
    assert "| MatMul | 4.0 / 5.0 / 6.0 | 60 % | 12 |" in md
    assert "peak RSS 112 MiB" in md and "+1.0 MiB from step 100" in md and "every 50 steps" in md


def test_profiling_does_not_import_torch():
    code = "import sys, radar_odom.latency, radar_odom.commands.profile; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ------------------------------------------------------------------ end to end
@pytest.fixture(scope="module")
def tiny_model(fast_learned_model, tmp_path_factory):
    """The committed seeded learned-mask model with the coarse-to-fine search, named ``tiny``."""
    import shutil

    path = tmp_path_factory.mktemp("profile") / "tiny.onnx"
    shutil.copyfile(fast_learned_model, path)
    return path


@pytest.mark.slow
def test_profile_command_end_to_end(tiny_model, tmp_path, capsys):
    from radar_odom.commands.cli import main

    out = tmp_path / "prof"
    args = ["profile", "--models", str(tiny_model), "--profiles", "--steps", "6", "--warmup", "1",
            "--reference-steps", "2", "--operator-steps", "2", "--rss-steps", "0", "--file-sweeps", "6",
            "-o", str(out), "--no-progress"]
    assert main(args) == 0
    report = json.loads((out / "profile.json").read_text())
    (m,) = report["models"]
    assert m["stages"]["graph"]["n"] == 6 and m["stages"]["step"]["median"] >= m["stages"]["graph"]["median"]
    assert m["search"]["band_rotations"] == 3
    assert abs(sum(v["share"] for v in m["operators"].values()) - 1) < 1e-6 and "MatMul" in m["operators"]
    assert set(m["reference"]) == {"exhaustive", "same_search"}
    # the numpy version of the same search agrees with the graph on the same masked images
    assert m["reference"]["same_search"]["pose_diff_median"]["x_m"] < 0.2
    # end to end on files: both modes stream every file, and the ratio is wall / slower stage
    for mode in ("pipelined", "serial"):
        f = m["files"][mode]
        assert f["sweeps"] == 6 and f["sweeps_per_s"] > 0
        assert f["ratio"] == pytest.approx(f["wall_per_sweep_s"] / max(f["load_median_s"], f["step_median_s"]))
    assert sorted(p.name for p in out.iterdir()) == ["profile.json", "profile.md"]  # no traces without --keep-traces
    assert "| tiny |" in (out / "profile.md").read_text()
    assert "End to end on files" in (out / "profile.md").read_text()
    printed = capsys.readouterr().out
    assert "machine:" in printed
    # every phase longer than a few seconds says when it starts (no silent minutes after the RSS line)
    for phase in ("the same search in numpy (pocketfft), 2 steps", "onnxruntime's profiler, 2 steps",
                  "6 sweeps from PNG files, pipelined and serial"):
        assert phase in printed, phase


@pytest.mark.slow
def test_rss_stream_in_a_fresh_process(tiny_model):
    from radar_odom.latency.memory import rss_stream

    r = rss_stream(tiny_model, steps=20, threads=1, every=10)
    assert [s[0] for s in r["samples"]] == [1, 10, 20]
    assert 0 < r["samples"][-1][1] <= r["peak_mb"] < 1000
    assert r["growth_from_step"] == 10 and r["growth_mb"] == pytest.approx(r["samples"][-1][1] - r["samples"][1][1])


def test_profile_defaults_are_the_shipped_models_and_help_explains_every_column(capsys):
    """`radar-odom profile` with no arguments times the shipped models only (cart-0.2, which is not
    shipped, on request); --help and the report explain every column of both tables."""
    from radar_odom import pretrained_names
    from radar_odom.commands.cli import main
    from radar_odom.commands.profile import default_profile_names
    from radar_odom.latency.columns import FILE_COLUMNS, LATENCY_COLUMNS

    assert default_profile_names() == pretrained_names() and "cart-0.2" not in default_profile_names()
    with pytest.raises(SystemExit):
        main(["profile", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for head, _ in LATENCY_COLUMNS + FILE_COLUMNS:
        assert f"{head}:" in text, head
    assert "'p2c'" in text and "--keep-traces" in text
    md = markdown_report(fake_report())
    for head, _ in LATENCY_COLUMNS:
        assert f"- *{head}*:" in md


def test_heartbeat_speaks_while_a_silent_phase_runs():
    import time

    from radar_odom._progress import heartbeat

    lines = []
    with heartbeat(lines.append, "numpy reference", every_s=0.05):
        time.sleep(0.28)
    assert 3 <= len(lines) <= 6 and lines[0].startswith("  … numpy reference: ") and lines[0].endswith(" s")
    time.sleep(0.1)
    assert len(lines) <= 6  # stopped with the phase


def test_summary_line_names_its_stages_and_flags_a_stream_faster_than_its_steps():
    from radar_odom.latency.runner import summary_line
    from radar_odom.latency.timing import ModelProfile

    stage = lambda ms: {"median": ms, "p90": ms, "p99": ms}  # noqa: E731
    r = ModelProfile("m", "m.onnx", {"resolution_m": 0.2}, None, True,
                     stages={"graph": stage(300.0), "step": stage(337.0), "polar_to_cartesian": stage(37.0),
                             "png_decode": stage(5.0)}, peak_rss_mb=100.0)
    r.files = {"pipelined": {"sweeps_per_s": 8.1, "wall_per_sweep_s": 1 / 8.1, "ratio": 1.0}}
    line = summary_line(r)
    assert "p2c" not in line and "step 337.0 ms (paper GPU 48.5 ms) = polar→Cartesian 37.0 ms + graph 300.0 ms" in line
    assert "123.5 ms per sweep" in line and "faster than the timed steps' 337.0 ms" in line
    r.files["pipelined"].update(sweeps_per_s=2.9, wall_per_sweep_s=1 / 2.9)
    assert "faster than" not in summary_line(r)


def test_profile_without_torch_for_an_unshipped_profile_names_the_way_out(monkeypatch, tmp_path):
    import subprocess

    from radar_odom.errors import RadarOdomError
    from radar_odom.latency import models

    monkeypatch.setattr(subprocess, "run", lambda *a, **k: subprocess.CompletedProcess(
        a, 1, "", "ModuleNotFoundError: No module named 'torch'"))
    with pytest.raises(RadarOdomError, match=r"--profiles.*--models PATH.onnx.*pip install -e \./export"):
        models.untrained_model("cart-0.2", tmp_path)
