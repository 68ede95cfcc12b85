"""Outputs never delete what they did not write (issue 51, item 1): `fleet` and `demo` write into a folder only
where it is new or holds their own earlier outputs (recognised by their manifest); anything else stops the
command in one line before any work, every input and foreign file left byte-identical. No Ray is started here:
every refusal comes before it (a run that reached Ray fails the test)."""
import hashlib
import importlib.util
import json
import shutil

import pytest
from conftest import one_error_line

from radar_odom.commands.cli import main
from radar_odom.errors import ConfigError, OutputError

NO_RAY = importlib.util.find_spec("ray") is None
needs_ray = pytest.mark.skipif(NO_RAY, reason='the fleet extra (Ray) is not installed: pip install -e ".[fleet]"')
FRAMES = 4



def snapshot(root) -> dict:
    """Every file below ``root`` with its SHA-256: equal snapshots, byte-identical trees."""
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    from radar_odom.sim import write_drive

    return write_drive(tmp_path_factory.mktemp("sim") / "drive", seed=3, frames=FRAMES, progress=False)


@pytest.fixture
def no_odometry(monkeypatch):
    """Any fleet that gets as far as Ray, or a recording's odometry, fails the test: refusals come first."""
    import radar_odom.fleet.job as job
    import radar_odom.fleet.scheduler as scheduler

    monkeypatch.setattr(scheduler, "_run_on_ray", lambda *a, **k: pytest.fail("the fleet reached Ray"))
    monkeypatch.setattr(job, "process_recording", lambda *a, **k: pytest.fail("a recording was processed"))


# ------------------------------------------------------------------------------------------- the shared rule
def test_a_folder_is_a_commands_own_only_where_its_manifest_lists_every_file(tmp_path):
    from radar_odom.outputs import check_output_folder, foreign_files, remove_own_outputs, write_folder_manifest

    folder = tmp_path / "out"
    assert check_output_folder(folder, ".m.json", "demo") is False  # absent: new
    folder.mkdir()
    assert check_output_folder(folder, ".m.json", "demo") is False  # empty: new
    (folder / "sub").mkdir()
    (folder / "sub" / "a.csv").write_text("a")
    (folder / "b.csv").write_text("b")
    write_folder_manifest(folder, ".m.json", "demo")
    assert json.loads((folder / ".m.json").read_text())["files"] == ["b.csv", "sub/a.csv"]
    assert check_output_folder(folder, ".m.json", "demo") is True
    (folder / "sub" / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match=r"holds 1 file\(s\) radar-odom demo did not write \(sub/notes.txt\)"):
        check_output_folder(folder, ".m.json", "demo")
    remove_own_outputs(folder, ".m.json")  # only what it lists: the user's file and its folder stay
    assert sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*")) == [".m.json", "sub", "sub/notes.txt"]
    (folder / ".m.json").write_text('{"files": ["../outside.txt"]}')
    (tmp_path / "outside.txt").write_text("x")
    remove_own_outputs(folder, ".m.json")  # an edited manifest pointing out of its folder is not followed
    assert (tmp_path / "outside.txt").read_text() == "x"
    assert foreign_files(tmp_path, ".m.json", names=["outside.txt", "absent"]) == ["outside.txt"]


# ------------------------------------------------------------------------------------------------- fleet
@needs_ray
def test_fleet_with_out_holding_the_recording_refuses_and_leaves_every_input_byte_identical(
        drive, tmp_path, capsys, no_odometry):
    drives = tmp_path / "drives"
    shutil.copytree(drive, drives / "drive")
    before = snapshot(drives)
    assert main(["fleet", str(drives / "drive"), "-o", str(drives), "--no-progress"]) == 1
    assert "outputs are never written among the inputs" in one_error_line(capsys, "fleet")
    assert snapshot(drives) == before
    # nor an OUT inside a recording
    assert main(["fleet", str(drives / "drive"), "-o", str(drives / "drive" / "out"), "--no-progress"]) == 1
    assert "is inside the recording" in one_error_line(capsys, "fleet")
    assert snapshot(drives) == before and not (drives / "drive" / "out").exists()


@needs_ray
def test_fleet_keeps_a_users_file_in_the_recordings_folder_and_refuses(drive, tmp_path, capsys, no_odometry):
    out = tmp_path / "OUT"
    (out / "drive").mkdir(parents=True)
    notes = out / "drive" / "my_notes.txt"
    notes.write_bytes(b"my own notes\n\x00\xff")
    assert main(["fleet", str(drive), "-o", str(out), "--no-progress"]) == 1
    line = one_error_line(capsys, "fleet")
    assert "did not write (my_notes.txt)" in line and "nothing was touched" in line
    assert notes.read_bytes() == b"my own notes\n\x00\xff"
    assert sorted(p.name for p in out.rglob("*")) == ["drive", "my_notes.txt"]


def test_a_second_recording_of_the_same_name_keeps_the_firsts_outputs(drive, cli_model, tmp_path, capsys,
                                                                      monkeypatch):
    from radar_odom.fleet.job import process_recording
    from radar_odom.fleet.scheduler import run_fleet

    van1, van2 = tmp_path / "van1" / "drive", tmp_path / "van2" / "drive"
    shutil.copytree(drive, van1)
    shutil.copytree(drive, van2)
    out = tmp_path / "OUT"
    out.mkdir()
    row = process_recording(str(cli_model), str(van1.resolve()), out, "drive", {"plot": False}, "k1")
    assert row["path"] == str(van1.resolve())
    kept = snapshot(out)
    assert "drive/estimates.csv" in kept and "drive/fleet-done.json" in kept
    # fleet van2/drive -o OUT: refused before any work, van1's outputs byte-identical
    import radar_odom.fleet.scheduler as scheduler

    monkeypatch.setattr(scheduler, "_run_on_ray", lambda *a, **k: pytest.fail("the fleet reached Ray"))
    with pytest.raises(OutputError, match=r"holds fleet's outputs of another recording \(.*van1/drive\)"):
        run_fleet([str(van2)], out, cli_model, {"plot": False}, show_progress=False)
    # and a worker given it anyway (the check raced) publishes nothing over it
    with pytest.raises(OutputError, match="another recording"):
        process_recording(str(cli_model), str(van2.resolve()), out, "drive", {"plot": False}, "k2")
    assert snapshot(out) == kept
    # the same recording again: fleet's own outputs, replaced (another key: another option)
    process_recording(str(cli_model), str(van1.resolve()), out, "drive", {"plot": False, "motion_prior": False}, "k3")
    assert json.loads((out / "drive" / "fleet-done.json").read_text())["key"] == "k3"
    assert sorted(p.name for p in out.iterdir()) == ["drive"]  # nothing set aside is left behind
    if not NO_RAY:  # the command line says it in one line
        assert main(["fleet", str(van2), "-o", str(out), "--model", str(cli_model), "--no-progress"]) == 1
        assert "another recording" in one_error_line(capsys, "fleet")


def test_a_recording_named_like_a_report_file_is_refused_up_front(tmp_path):
    from radar_odom.fleet.manifest import recording_names

    for name in ("fleet.csv", "fleet.md", "FLEET.CSV", "fleet-error.png"):
        with pytest.raises(ConfigError, match=f"a recording named {name} would write its outputs to OUT/{name}"):
            recording_names([tmp_path / "x" / name, tmp_path / "y"])
    assert recording_names([tmp_path / "a" / "fleet.csv.d"]) == ["fleet.csv.d"]


@needs_ray
def test_fleet_refuses_a_recording_named_fleet_csv_before_any_work(drive, tmp_path, capsys, no_odometry):
    odd = tmp_path / "rec" / "fleet.csv"
    shutil.copytree(drive, odd)
    out = tmp_path / "OUT"
    assert main(["fleet", str(odd), "-o", str(out), "--no-progress"]) == 1
    assert "the fleet report's own name" in one_error_line(capsys, "fleet")
    assert not out.exists()


@needs_ray
def test_fleet_refuses_report_names_in_out_that_it_did_not_write(drive, tmp_path, capsys, no_odometry):
    from radar_odom.fleet.report import COLUMNS, check_reports, claim_reports

    out = tmp_path / "OUT"
    out.mkdir()
    (out / "fleet.md").write_text("# my own page\n")
    assert main(["fleet", str(drive), "-o", str(out), "--no-progress"]) == 1
    assert "holds fleet.md, which radar-odom fleet did not write" in one_error_line(capsys, "fleet")
    assert (out / "fleet.md").read_text() == "# my own page\n"
    claim_reports(out)  # claimed by fleet's manifest: its own
    check_reports(out)
    legacy = tmp_path / "legacy"
    legacy.mkdir()
    (legacy / "fleet.csv").write_text(",".join(COLUMNS) + "\n")  # a fleet older than the manifest
    (legacy / "fleet.md").write_text("# Fleet report\n")
    check_reports(legacy)


def test_publish_replaces_only_fleets_own_earlier_folder(tmp_path):
    from radar_odom.fleet.job import publish
    from radar_odom.fleet.manifest import write_manifest

    final = tmp_path / "rec"
    final.mkdir()
    (final / "notes.txt").write_text("mine")
    new = tmp_path / ".rec.tmp-1"
    new.mkdir()
    (new / "estimates.csv").write_text("new")
    write_manifest(new, "k", {"path": str(tmp_path / "src" / "rec")})
    with pytest.raises(OutputError, match=r"did not write \(notes.txt\)"):
        publish(new, final)
    assert (final / "notes.txt").read_text() == "mine" and new.is_dir()


# -------------------------------------------------------------------------------------------------- demo
def test_demo_replaces_its_own_earlier_outputs_and_refuses_a_folder_holding_anything_else(cli_model, tmp_path,
                                                                                          capsys):
    out = tmp_path / "radar-odom-demo"
    demo = ["demo", "--model", str(cli_model), "-o", str(out), "--frames"]
    assert main([*demo, "3"]) == 0
    manifest = json.loads((out / ".radar-odom-demo.json").read_text())
    assert "trajectory.tum" in manifest["files"] and any(f.startswith("drive/radar/") for f in manifest["files"])
    # a later demo (another drive: another seed) replaces its own earlier files, sweeps included
    assert main([*demo, "3", "--seed", "9006"]) == 0
    capsys.readouterr()
    assert sorted(snapshot(out)) == sorted(json.loads((out / ".radar-odom-demo.json").read_text())["files"]
                                           + [".radar-odom-demo.json"])
    # a file it did not write, at the top or inside its drive: refused before any work, kept byte-identical
    for notes in (out / "my_notes.txt", out / "drive" / "notes.txt"):
        notes.write_bytes(b"mine\x00")
        before = snapshot(out)
        assert main([*demo, "4"]) == 1
        assert "radar-odom demo did not write" in one_error_line(capsys, "demo")
        assert snapshot(out) == before
        notes.unlink()
    # a user's folder that is no demo's at all
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("x")
    assert main([*demo, "3"][:-2] + ["-o", str(mine), "--frames", "3"]) == 1
    one_error_line(capsys, "demo")
    assert [p.name for p in mine.iterdir()] == ["thesis.tex"]
