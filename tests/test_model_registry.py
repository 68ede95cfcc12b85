"""The model registry (issue 52, item 4): every shipped model listed with its digest, `pretrained` checking it,
`radar-odom models`, and a user's own models under $RADAR_ODOM_HOME. Runtime only (no torch); the shipped files
are never modified: every damaged file is a copy under tmp_path."""
import hashlib
import json
import os
import shutil
from pathlib import Path

import pytest
from conftest import one_error_line

import radar_odom
from radar_odom import model_registry, model_zoo
from radar_odom.commands.cli import main
from radar_odom.errors import (
    InvalidModelError,
    ModelDigestError,
    ModelMismatchError,
    ModelNotFoundError,
    RadarOdomError,
    RegistryError,
)
from radar_odom.model_zoo import UnknownModelError

SHIPPED = model_zoo.MODELS_DIR
SCORECARD = Path(__file__).resolve().parents[1] / "docs" / "scorecard.md"


def shipped_registry() -> dict:
    entries = model_registry.read_registry(SHIPPED, "shipped")
    assert entries is not None, f"{SHIPPED / 'registry.json'} is missing"
    return entries


def copy_shipped(dest: Path, names=("cart-0.8",)) -> Path:
    """The shipped registry and the named files, copied to ``dest`` (a models folder of the test's own)."""
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(SHIPPED / "registry.json", dest / "registry.json")
    for name in names:
        shutil.copyfile(SHIPPED / f"{name}.onnx", dest / f"{name}.onnx")
    return dest


def flip_byte(path: Path, offset: int | None = None) -> None:
    data = bytearray(path.read_bytes())
    i = len(data) // 2 if offset is None else offset
    data[i] ^= 0x01
    path.write_bytes(bytes(data))


# --------------------------------------------------------------------------- the shipped registry
def test_the_registry_lists_every_shipped_file_with_its_digest_and_size():
    entries = shipped_registry()
    files = sorted(p.stem for p in SHIPPED.glob("*.onnx"))
    assert sorted(entries) == files, (
        "radar_odom/models/registry.json must list every shipped .onnx file and no other: "
        "run `python -m radar_odom.model_registry --refresh`, then check its scorecard quotes")
    for name, e in entries.items():
        data = e.path.read_bytes()
        assert e.path == SHIPPED / f"{name}.onnx"
        assert hashlib.sha256(data).hexdigest() == e.sha256, name
        assert len(data) == e.size, name
    assert model_zoo.pretrained_names() == files  # no local models in the suite (conftest's RADAR_ODOM_HOME)


def test_the_registry_descriptions_are_the_files_own_metadata():
    """grid, form, search, training and calibration are read from each file's metadata, never typed in."""
    for name, e in shipped_registry().items():
        facts = model_registry.describe(e.path)
        assert {k: getattr(e, k) for k in model_registry.DESCRIPTION_FIELDS} == \
               {k: facts[k] for k in model_registry.DESCRIPTION_FIELDS}, name
    e = shipped_registry()["cart-0.4"]
    assert e.grid == "0.4 m × 256 px" and e.form == "stream" and e.search == "fast (c4s6b2)"
    assert "seeds 1000–1009" in e.trained_on and "radiate-2019-02-12-edinburgh" in e.calibrated_on


def test_the_scorecard_quotes_are_in_docs_scorecard_md_under_their_dated_heading():
    if not SCORECARD.is_file():
        pytest.skip(f"{SCORECARD} is not in this installation")
    text = SCORECARD.read_text(encoding="utf-8")
    for name, e in shipped_registry().items():
        sc = e.scorecard
        assert sc and {"date", "section", "line"} <= set(sc), f"{name}: no scorecard quote"
        assert sc["date"] in sc["section"], (name, sc)
        heading = f"## {sc['section']}\n"
        assert heading in text, f"{name}: docs/scorecard.md has no heading {heading!r}: update registry.json"
        section = text.split(heading, 1)[1].split("\n## ", 1)[0]
        assert sc["line"] in section.splitlines(), f"{name}: {sc['line']!r} is not a line of {sc['section']!r}"


# --------------------------------------------------------------------------- the digest check
def test_pretrained_checks_the_digest_and_a_corrupted_byte_is_a_typed_error(tmp_path, monkeypatch):
    good = copy_shipped(tmp_path / "good")
    monkeypatch.setattr(model_zoo, "MODELS_DIR", good)
    assert radar_odom.pretrained("cart-0.8") == str(good / "cart-0.8.onnx")

    bad = copy_shipped(tmp_path / "bad")
    flip_byte(bad / "cart-0.8.onnx")
    found = hashlib.sha256((bad / "cart-0.8.onnx").read_bytes()).hexdigest()
    expected = shipped_registry()["cart-0.8"].sha256
    monkeypatch.setattr(model_zoo, "MODELS_DIR", bad)
    with pytest.raises(ModelDigestError) as err:
        radar_odom.pretrained("cart-0.8")
    msg = str(err.value)
    assert isinstance(err.value, InvalidModelError) and isinstance(err.value, RadarOdomError)
    assert str(bad / "cart-0.8.onnx") in msg and expected in msg and found in msg
    assert "reinstall radar-odom" in msg and "same size" not in msg and "10344224 bytes, as expected" in msg
    assert (err.value.expected, err.value.found) == (expected, found)
    # the path given as models_dir is checked the same way; resolve_model (`--model NAME`) too
    with pytest.raises(ModelDigestError):
        model_zoo.pretrained("cart-0.8", bad)
    with pytest.raises(ModelDigestError):
        model_zoo.resolve_model("cart-0.8")


def test_the_digest_cache_sees_a_file_changed_in_place(tmp_path, monkeypatch):
    """`file_sha256` hashes once per process; a file rewritten later (a new mtime) is hashed again."""
    d = copy_shipped(tmp_path / "m")
    monkeypatch.setattr(model_zoo, "MODELS_DIR", d)
    path = d / "cart-0.8.onnx"
    assert radar_odom.pretrained("cart-0.8") == str(path)
    st = path.stat()
    flip_byte(path, offset=100)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))  # a later mtime, as any later write gives
    with pytest.raises(ModelDigestError):
        radar_odom.pretrained("cart-0.8")


def test_a_missing_file_and_an_unknown_name_are_each_one_typed_error(tmp_path, monkeypatch, capsys):
    d = copy_shipped(tmp_path / "m", names=("cart-0.8",))  # the registry lists cart-0.4 too; its file is absent
    monkeypatch.setattr(model_zoo, "MODELS_DIR", d)
    with pytest.raises(ModelNotFoundError, match=r"cart-0\.4\.onnx: the shipped model 'cart-0\.4' is listed in "
                                                 r".*registry\.json but its file is missing; reinstall"):
        radar_odom.pretrained("cart-0.4")
    with pytest.raises(UnknownModelError, match=r"no pretrained model 'cart-9'; shipped models: cart-0\.4, cart-0\.8"):
        radar_odom.pretrained("cart-9")
    # on the command line: one line each, no traceback
    assert main(["demo", "--frames", "3", "--model", "cart-0.4", "-o", str(tmp_path / "demo")]) == 1
    assert "its file is missing" in one_error_line(capsys, "demo")
    assert main(["demo", "--frames", "3", "--model", "cart-9", "-o", str(tmp_path / "demo")]) == 1
    assert "no pretrained model 'cart-9'" in one_error_line(capsys, "demo")
    # `radar-odom models` lists it as missing and exits 1, saying why
    assert main(["models"]) == 1
    out, err = capsys.readouterr()
    row = next(ln for ln in out.splitlines() if ln.startswith("cart-0.4 "))
    assert row.endswith("MISSING") and "its file is missing" in err


def test_a_malformed_registry_is_a_typed_error_naming_it(tmp_path, monkeypatch):
    d = copy_shipped(tmp_path / "m")
    monkeypatch.setattr(model_zoo, "MODELS_DIR", d)
    reg = json.loads((d / "registry.json").read_text())
    reg["models"]["cart-0.8"]["file"] = "../cart-0.8.onnx"  # a path out of the folder
    (d / "registry.json").write_text(json.dumps(reg))
    with pytest.raises(RegistryError, match=r"registry\.json: entry 'cart-0\.8': \"file\" must be a file name"):
        radar_odom.pretrained("cart-0.8")
    (d / "registry.json").write_text("{not json")
    with pytest.raises(RegistryError, match="not a readable JSON registry"):
        radar_odom.pretrained_names()


# --------------------------------------------------------------------------- radar-odom models
def test_radar_odom_models_prints_every_model(capsys):
    assert main(["models"]) == 0
    out = capsys.readouterr().out
    entries = shipped_registry()
    rows = {ln.split()[0]: ln for ln in out.splitlines() if len(ln.split()) > 1 and ln.split()[0] in entries}
    assert sorted(rows) == sorted(entries) == radar_odom.pretrained_names()
    for name, e in entries.items():
        assert f" {e.size} " in rows[name] and e.sha256[:16] in rows[name] and rows[name].endswith("ok")
        assert e.sha256 in out and e.scorecard["date"] in out
    assert main(["models", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert [m["name"] for m in listed] == sorted(entries)
    assert all(m["check"] == "ok" and m["sha256"] == entries[m["name"]].sha256 for m in listed)


def test_a_local_model_is_added_listed_loaded_and_checked(fast_learned_model, foreign_model, tmp_path,
                                                          monkeypatch, capsys):
    from radar_odom.odometry.odometer import RadarOdometer

    home = tmp_path / "home"
    monkeypatch.setenv("RADAR_ODOM_HOME", str(home))
    assert main(["models", "--add", "mine", str(fast_learned_model)]) == 0
    assert "added mine" in capsys.readouterr().out
    local = home / "models" / "mine.onnx"
    assert local.read_bytes() == fast_learned_model.read_bytes()
    reg = json.loads((home / "models" / "registry.json").read_text())
    assert reg["models"]["mine"]["sha256"] == hashlib.sha256(local.read_bytes()).hexdigest()
    assert radar_odom.pretrained_names() == sorted(shipped_registry()) + ["mine"]
    assert radar_odom.pretrained("mine") == str(local) == model_zoo.resolve_model("mine")
    RadarOdometer(radar_odom.pretrained("mine"), threads=1)  # loads
    assert main(["models"]) == 0
    row = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("mine "))
    assert " local " in row and row.endswith("ok")

    # refused: a shipped name, a name taken (without --force), a file that is not a radar-odom model
    assert main(["models", "--add", "cart-0.4", str(fast_learned_model)]) == 1
    assert "shipped model's name" in one_error_line(capsys, "models")
    assert main(["models", "--add", "mine", str(fast_learned_model)]) == 1
    assert "--force" in one_error_line(capsys, "models")
    with pytest.raises(ModelMismatchError, match="not a radar-odom model"):
        model_registry.add_local("other", foreign_model)
    assert not (home / "models" / "other.onnx").exists()

    # damaged after it was added: the same typed error, saying how to add it again
    flip_byte(local)
    with pytest.raises(ModelDigestError, match=r"local model 'mine' is damaged.*--add mine FILE\.onnx --force"):
        radar_odom.pretrained("mine")
    assert main(["models", "--add", "mine", str(fast_learned_model), "--force"]) == 0
    assert radar_odom.pretrained("mine") == str(local)
    assert main(["models", "--remove", "mine"]) == 0
    assert not local.exists() and radar_odom.pretrained_names() == sorted(shipped_registry())
    with pytest.raises(UnknownModelError):
        radar_odom.pretrained("mine")


def test_a_hand_written_local_entry_loads_with_the_same_check(fast_learned_model, tmp_path, monkeypatch):
    home = tmp_path / "home"
    monkeypatch.setenv("RADAR_ODOM_HOME", str(home))
    (home / "models").mkdir(parents=True)
    shutil.copyfile(fast_learned_model, home / "models" / "own.onnx")
    data = fast_learned_model.read_bytes()
    entry = {"file": "own.onnx", "sha256": hashlib.sha256(data).hexdigest(), "size": len(data)}
    (home / "models" / "registry.json").write_text(json.dumps(
        {"format": model_registry.FORMAT, "models": {"own": entry}}))
    assert radar_odom.pretrained("own") == str(home / "models" / "own.onnx")
    entry["sha256"] = "0" * 64
    (home / "models" / "registry.json").write_text(json.dumps(
        {"format": model_registry.FORMAT, "models": {"own": entry}}))
    with pytest.raises(ModelDigestError, match="0{64}"):
        radar_odom.pretrained("own")
