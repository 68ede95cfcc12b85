"""The aarch64 job of .ci/run (issue 52, item 5): its logic offline (pip's answers stubbed); the real check
needs PyPI and runs in CI (`python .ci/aarch64_wheels.py`)."""
import sys

from fixtures import ROOT, load_script


def load_check():
    return load_script(".ci/aarch64_wheels.py")


def test_it_checks_every_runtime_dependency_of_pyproject():
    if sys.version_info >= (3, 11):
        import tomllib

        project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
        assert load_check().runtime_dependencies() == project["dependencies"]
    ci = (ROOT / ".ci" / "run").read_text()
    assert '.ci/aarch64_wheels.py --python-version 3.11 || arm_rc=$?' in ci
    assert ci.rstrip().splitlines()[-1].endswith('[ "$arm_rc" -eq 0 ]')  # the job fails the CI


def test_it_says_which_platform_each_resolves_as_and_fails_on_none(monkeypatch, capsys):
    check = load_check()
    monkeypatch.setattr(check, "runtime_dependencies", lambda: ["a>=1", "b>=2", "c>=3"])
    wheels = {("a>=1", "manylinux2014_aarch64"): "a-1-cp311-manylinux2014_aarch64.whl",
              ("b>=2", "manylinux_2_28_aarch64"): "b-2-cp311-manylinux_2_28_aarch64.whl"}

    def fetch(spec, platform, python_version, dest):
        name = wheels.get((spec, platform))
        return (name, "") if name else (None, f"ERROR: No matching distribution found for {spec}")

    monkeypatch.setattr(check, "fetch", fetch)
    assert check.main([]) == 1
    out, err = capsys.readouterr()
    assert "a>=1: manylinux2014_aarch64: a-1-cp311" in out
    assert "b>=2: manylinux_2_28_aarch64: b-2-cp311" in out and "needs glibc ≥ 2.28" in out
    assert "c>=3: NO aarch64 wheel" in out and "No matching distribution found for c>=3" in out
    assert "2 of 3 runtime dependencies resolve" in out and "only as manylinux_2_28 (glibc ≥ 2.28): b>=2" in out
    assert "aarch64 check failed: c>=3" in err
    # all resolve: passes
    monkeypatch.setattr(check, "fetch", lambda spec, platform, pv, dest: (f"{spec[0]}.whl", ""))
    assert check.main([]) == 0
    assert "3 of 3 runtime dependencies resolve" in capsys.readouterr().out
