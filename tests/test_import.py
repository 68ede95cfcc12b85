import importlib.util
import subprocess
import sys


def test_import_radar_odom_never_imports_torch():
    code = (
        "import sys, radar_odom\n"
        "from radar_odom import *\n"
        "import radar_odom.commands.cli\n"
        "radar_odom.commands.cli.build_parser()\n"
        "bad = [m for m in sys.modules if m == 'torch' or m.startswith('torch.')]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_cli_help_lists_commands():
    out = subprocess.run(
        [sys.executable, "-m", "radar_odom", "--help"], capture_output=True, text=True, check=True
    ).stdout
    assert "radar-odom" in out


def test_pretrained_is_the_function_and_no_module_shadows_it():
    """`radar_odom.pretrained` is the public function; the module defining it has another name
    (`model_zoo`), so importing any submodule first cannot rebind the package attribute."""
    code = (
        "import importlib, pkgutil, radar_odom\n"
        "names = [m.name for m in pkgutil.iter_modules(radar_odom.__path__)]\n"
        "assert 'pretrained' not in names, names\n"
        "import radar_odom.model_zoo, radar_odom.odometry.odometer, radar_odom.commands.run_demo\n"
        "assert callable(radar_odom.pretrained), radar_odom.pretrained\n"
        "from radar_odom import pretrained\n"
        "assert callable(pretrained)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# ------------------------------------------------------------------ no import cycles (issue 13)
def _module_graph() -> dict[str, set[str]]:
    """Project module -> project modules it imports anywhere in its file (function-level imports
    included: a lazy import that closes a cycle is still a cycle), from the source text."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    files = {}
    for pkg, folder in (("radar_odom", root / "sdk" / "radar_odom"),
                        ("radar_odom_export", root / "export" / "radar_odom_export")):
        for f in folder.rglob("*.py"):
            parts = [pkg, *f.relative_to(folder).with_suffix("").parts]
            files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    graph = {}
    for mod, f in files.items():
        deps = set()
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = mod.split(".") if f.name == "__init__.py" else mod.split(".")[:-1]
                base = base[: len(base) - node.level + 1] if node.level else []
                prefix = ".".join(base + ([node.module] if node.module else []))
                names = [prefix] + [f"{prefix}.{a.name}" for a in node.names]
            else:
                continue
            # importing a submodule runs its parent packages first: those edges are not cycles
            deps.update(n for n in names if n in files and n != mod and not mod.startswith(n + "."))
        graph[mod] = deps
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycles_in_the_project():
    graph = _module_graph()
    assert "radar_odom_export.onnx_export" in graph and "radar_odom.odometry.odometer" in graph
    assert "radar_odom_export.fast_search" in graph["radar_odom_export.onnx_export"]
    assert _cycles(graph) == []


# ------------------------------------------------------------------ the folders are layers (issue 31)
# folder -> the other folders it may import (docs/ARCHITECTURE.md, "Who imports whom"); every
# folder may import the shared vocabulary (the package's top-level modules)
ALLOWED_FOLDERS = {
    "odometry": {"io"},      # pipeline.iter_estimates reads a folder it is given
    "io": {"ros"},           # bags: messages converted by ros.msgs
    "ros": {"io"},           # the PNG header reader of io._layout
    "evaluation": {"io"},    # the GNSS/INS reference through io.gnss_ins
    "latency": {"odometry", "io", "evaluation", "sim"},  # profiles on simulated sweeps
    "sim": {"io", "evaluation"},
    "runs": {"odometry", "io", "evaluation"},  # run_sequence: a recording read, run, written and evaluated
    "commands": {"odometry", "io", "ros", "evaluation", "latency", "sim", "fleet", "runs"},
    "fleet": {"runs", "odometry", "evaluation"},  # run_sequence per recording (never the CLI layer); the report
}


def _folder(mod: str) -> str | None:
    """'odometry' for radar_odom.odometry.x, None for a top-level (shared vocabulary) module."""
    parts = mod.split(".")
    if parts[0] != "radar_odom" or len(parts) < 2:
        return None
    return parts[1] if parts[1] in ALLOWED_FOLDERS else None


def _layering_violations(graph: dict[str, set[str]]) -> list[str]:
    """Imports across runtime folders that ALLOWED_FOLDERS does not list, and imports of a folder
    from the shared vocabulary (the entry point ``radar_odom.__main__`` aside)."""
    wrong = []
    for mod, deps in graph.items():
        if not mod.startswith("radar_odom.") or mod == "radar_odom.__main__":
            continue
        here = _folder(mod)
        for dep in sorted(deps):
            there = _folder(dep)
            if there is None or there == here:
                continue
            if here is None:
                wrong.append(f"{mod} (shared vocabulary) imports {dep}")
            elif there not in ALLOWED_FOLDERS[here]:
                wrong.append(f"{mod} ({here}/) imports {dep} ({there}/)")
    return wrong


def test_runtime_folders_import_only_what_the_architecture_allows():
    graph = _module_graph()
    assert {_folder(m) for m in graph} >= set(ALLOWED_FOLDERS)
    assert _layering_violations(graph) == []


def test_the_layering_check_sees_a_wrong_import():
    assert _layering_violations({
        "radar_odom.odometry.odometer": {"radar_odom.commands.run", "radar_odom.scan", "radar_odom.io"},
        "radar_odom.scan": {"radar_odom.odometry.odometer"},
        "radar_odom.__main__": {"radar_odom.commands.cli"},
        "radar_odom.io.bag": {"radar_odom.ros.msgs"},
    }) == ["radar_odom.odometry.odometer (odometry/) imports radar_odom.commands.run (commands/)",
           "radar_odom.scan (shared vocabulary) imports radar_odom.odometry.odometer"]


def _export_reaching_into_commands(graph: dict[str, set[str]]) -> list[str]:
    """Imports from the torch side (``radar_odom_export``) up into the command line (``radar_odom.commands``):
    the exporter sits beside the runtime's lower layers, below ``commands/`` (issue 42, item 6). Its own
    subcommands (``radar_odom_export.commands``, issue 52) are the command line and may."""
    return [f"{mod} imports {dep}" for mod, deps in sorted(graph.items())
            if mod.startswith("radar_odom_export") and not mod.startswith("radar_odom_export.commands")
            for dep in sorted(deps) if dep == "radar_odom.commands" or dep.startswith("radar_odom.commands.")]


def test_the_export_package_never_imports_the_command_line():
    graph = _module_graph()
    assert "radar_odom.io.recording" in graph["radar_odom_export.adapt"]
    assert "radar_odom.model_zoo" in graph["radar_odom_export.adapt"]
    assert _export_reaching_into_commands(graph) == []


def test_the_export_layering_check_sees_a_wrong_import():
    assert _export_reaching_into_commands({
        "radar_odom_export.adapt": {"radar_odom.commands.export", "radar_odom.io.recording"},
        "radar_odom_export.train": {"radar_odom.commands"},
        "radar_odom.commands.adapt": {"radar_odom_export.adapt"},
        "radar_odom_export.commands.adapt": {"radar_odom.commands", "radar_odom_export.adapt"},
    }) == ["radar_odom_export.adapt imports radar_odom.commands.export",
           "radar_odom_export.train imports radar_odom.commands"]


def test_every_command_help_prints_no_doubled_percent():
    """Descriptions use RawDescriptionHelpFormatter, which leaves '%%' as typed (issue 24 found
    `train --help` printing "20%%"); every subcommand's help must read as written."""
    from radar_odom.commands.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    assert "train" in sub.choices
    for name, p in sub.choices.items():
        text = p.format_help()
        assert "%%" not in text, (name, text[text.index("%%") - 60: text.index("%%") + 10])
    if importlib.util.find_spec("radar_odom_export") is not None:  # train's own help (the torch side's)
        assert "20 %" in sub.choices["train"].format_help()
