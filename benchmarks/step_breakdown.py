"""Where the stream step's time goes: onnxruntime's own profiler, per stage and operator class.

    python benchmarks/step_breakdown.py                      # cart-0.4, the fast search, 2 threads; ≈ 1 min
    python benchmarks/step_breakdown.py --checkpoint export/radar_odom_export/checkpoints/cart-0.8.pt

The checkpoint is exported with the fast search as `radar-odom export` does (the shipped file's graph),
but with the exporter's per-node scopes kept (the shipped files drop them), so every node can be
attributed to the module that made it: the masker (input normalisation, U-Net, feature filters), the
polar rotation of the candidates, the forward DFTs (and the state's layout changes), the spectrum
products, the windowed inverse DFT, the read-out (soft-argmax / parabola and covariance), and the
coarse yaw search's own rotation, DFTs and inverse. onnxruntime's profiler
(``SessionOptions.enable_profiling``) times every node over ``--steps`` streaming steps; its kernel
times are summed per stage and per operator type.

FLOPs per stage are counted from the graph's inferred shapes: MatMul 2·M·N·K, Conv 2·Cout·Cin/g·kh·kw
per output, elementwise one per output element, GatherElements one per gathered value (a memory
read, not arithmetic: shown apart). The machine's matmul peak is a large MatMul in onnxruntime on the
same threads, measured in the same run; *% of peak* = the stage's FLOPs per second of its kernel time
over that peak.
"""
from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CHECKPOINT = ROOT / "export" / "radar_odom_export" / "checkpoints" / "cart-0.4.pt"

STAGES = ("masker", "rotation", "forward DFT", "spectrum products", "inverse DFT", "read-out", "state layout",
          "coarse: rotation", "coarse: DFTs", "coarse: products", "coarse: inverse DFT", "coarse: pick",
          "other")
MASKER_OPS = {"Conv", "MaxPool", "Upsample", "Resize", "ReorderInput", "ReorderOutput"}  # NCHWc kernels
ELEMENTWISE = {"Add", "Sub", "Mul", "Div", "Relu", "Sigmoid", "Exp", "Sqrt", "Abs", "Max", "Min", "Where",
               "Clip", "Neg", "Pow", "Softmax", "ReduceSum", "ReduceMax", "ReduceMean", "Floor", "Round"}
PRODUCT_OPS = {"Mul", "Add", "Sub", "Concat", "Unsqueeze", "Slice", "Split"}


def module_classes(node) -> list[str]:
    """The class names of the modules whose ``forward`` made ``node`` (outermost first), from the
    exporter's scope metadata."""
    meta = {p.key: p.value for p in node.metadata_props}
    hierarchy = json.loads(meta.get("pkg.torch.onnx.class_hierarchy", "[]").replace("'", '"'))
    return [c.rsplit(".", 1)[-1] for c in hierarchy[:-1]]


def graph_stages(proto) -> dict:
    """{node name: stage (`STAGES`)} of a fast-search stream graph with its scopes kept.

    Modules called through ``forward`` name their nodes (normaliser, U-Net, the factored DFT, the
    windowed inverse, the low-res image, the coarse selector); the rest of the step (the polar
    rotation, whose methods are called directly, the feature filters, the read-out) is placed by
    data flow: the rotation is what lies between the features (the input of the DFT whose output
    becomes the state) and the rotated stack (the other DFT's input), the read-out is what follows
    the windowed inverse; in the coarse selector, its rotation lies between its low-res image and
    its DFT's input."""
    producer = {o: n for n in proto.graph.node for o in n.output}
    consumers = defaultdict(list)
    for n in proto.graph.node:
        for i in n.input:
            consumers[i].append(n)
    classes = {n.name: module_classes(n) for n in proto.graph.node}

    def ancestors(tensors) -> set:
        seen, todo = set(), list(tensors)
        while todo:
            node = producer.get(todo.pop())
            if node is not None and node.name not in seen:
                seen.add(node.name)
                todo.extend(node.input)
        return seen

    def descendants(nodes) -> set:
        seen, todo = set(), [n for n in nodes]
        while todo:
            node = todo.pop()
            if node.name in seen:
                continue
            seen.add(node.name)
            todo.extend(c for o in node.output for c in consumers[o])
        return seen

    def entry_inputs(cls: str, coarse: bool) -> list[str]:
        """Graph tensors entering the nodes of module class ``cls`` from outside it."""
        inside = [n for n in proto.graph.node if cls in classes[n.name]
                  and ("CoarseYawSelector" in classes[n.name]) == coarse]
        names = {n.name for n in inside}
        return [i for n in inside for i in n.input
                if i in producer and producer[i].name not in names and "Constant" not in producer[i].op_type]

    fine_in = entry_inputs("FactoredSpectrum", False)
    # the features: the DFT input that is an ancestor of another DFT input (the rotated stack)
    features = [t for t in fine_in if any(producer[t].name in ancestors([u]) for u in fine_in if u != t)]
    rotated = [t for t in fine_in if t not in features]
    state = [o.name for o in proto.graph.output if o.name == "state"]
    rotation = ancestors(rotated) - ancestors(features) - ancestors(state)
    coarse_image = [n for n in proto.graph.node if "LowResImage" in classes[n.name]]
    coarse_rotation = descendants(coarse_image) & ancestors(entry_inputs("FactoredSpectrum", True))
    readout = descendants([n for n in proto.graph.node if "WindowedInverse" in classes[n.name]
                           and "CoarseYawSelector" not in classes[n.name]])
    masker = ancestors(features)
    stages = {}
    for n in proto.graph.node:
        cls = " ".join(classes[n.name])
        coarse = "CoarseYawSelector" in cls
        if "WindowedInverse" in cls:
            product = n.op_type in PRODUCT_OPS and any(
                producer.get(i) is not None and "WindowedInverse" not in " ".join(classes[producer[i].name])
                for i in n.input) or n.op_type in ("Mul",)
            st = ("coarse: products" if coarse else "spectrum products") if product else \
                ("coarse: inverse DFT" if coarse else "inverse DFT")
        elif "FactoredSpectrum" in cls or "LowResImage" in cls:
            st = "coarse: DFTs" if coarse else "forward DFT"
        elif coarse:
            st = "coarse: rotation" if n.name in coarse_rotation else "coarse: pick"
        elif n.name in rotation:
            st = "rotation"
        elif "CartesianNormaliser" in cls or "UNet" in cls or n.name in masker:
            st = "masker"
        elif n.name in readout:
            st = "read-out"
        else:
            st = "state layout"
        stages[n.name] = st
    return stages


def profiled_name(name: str, op: str, stages: dict) -> str:
    """The graph node an onnxruntime profile entry stands for (its optimiser renames fused nodes:
    ``relu_3_nchwc`` is the Conv fused with ``node_relu_3``, ``x/GatherSliceToSplitFusion`` is x)."""
    base = name.split("/")[0]
    for cand in (base, "node_" + base, re.sub(r"_nchwc$", "", base), "node_" + re.sub(r"_nchwc$", "", base)):
        if cand in stages:
            return cand
    return ""


def scoped_export(checkpoint: Path, out: Path, settings: dict | None = None) -> Path:
    """Export ``checkpoint`` with the fast search to ``out``, keeping the per-node scope metadata."""
    import radar_odom_export.onnx_export as oe

    keep = oe.strip_node_metadata
    oe.strip_node_metadata = lambda proto: 0  # the scopes are what this script reads
    try:
        oe.export_checkpoint(str(checkpoint), str(out), search="fast", search_settings=settings, verify=False)
    finally:
        oe.strip_node_metadata = keep
    return out


def node_stages(path: Path) -> tuple[dict, dict]:
    """({node name: stage}, {node name: (op type, flops, gathered values)}) of an exported graph."""
    import onnx

    proto = onnx.shape_inference.infer_shapes(onnx.load(str(path)))
    shapes = {}
    for v in list(proto.graph.value_info) + list(proto.graph.input) + list(proto.graph.output):
        dims = [d.dim_value for d in v.type.tensor_type.shape.dim]
        shapes[v.name] = dims
    for t in proto.graph.initializer:
        shapes[t.name] = list(t.dims)
    stages, cost = graph_stages(proto), {}
    for node in proto.graph.node:
        out = shapes.get(node.output[0]) if node.output else None
        n_out = int(np.prod(out)) if out else 0
        flops, gathered = 0, 0
        if node.op_type == "MatMul" and out:
            k = shapes.get(node.input[0], [0])[-1]
            flops = 2 * n_out * k
        elif node.op_type == "Conv" and out:
            w = shapes.get(node.input[1], [0, 0, 0, 0])
            flops = 2 * n_out * w[1] * w[2] * w[3]  # w[1] is already Cin / group
        elif node.op_type in ELEMENTWISE:
            flops = n_out
        elif node.op_type in ("GatherElements", "Gather", "GatherND"):
            gathered = n_out
        cost[node.name] = (node.op_type, flops, gathered)
    return stages, cost


def profile_nodes(path: Path, steps: int, warmup: int, threads: int, spinning: bool = False,
                  optimization: str | None = None) -> dict:
    """{node name: (op type, mean kernel µs per step)} over ``steps`` streaming steps, with the SDK's
    session settings (`radar_odom.onnx_model.session_options`) but ``spinning`` and ``optimization``."""
    import onnxruntime as ort

    from radar_odom.onnx_model import session_options

    so = session_options(threads, True, path.with_suffix(""), spinning, optimization)
    sess = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
    sweep, state = (i.name for i in sess.get_inputs())
    shape = sess.get_inputs()[0].shape
    x = (np.random.default_rng(0).random(shape) ** 8).astype(np.float32)
    s = np.zeros(sess.get_inputs()[1].shape, np.float32)
    for _ in range(warmup):
        s = sess.run(None, {sweep: x, state: s})[2]
    for _ in range(steps):
        s = sess.run(None, {sweep: x, state: s})[2]
    events = json.loads(Path(sess.end_profiling()).read_text())
    totals = defaultdict(float)
    ops = {}
    runs = sorted(e["ts"] for e in events if e.get("cat") == "Session" and e.get("name") == "model_run")
    first_timed = runs[warmup] if len(runs) > warmup else 0
    for e in events:
        if e.get("cat") != "Node" or not e["name"].endswith("_kernel_time") or e["ts"] < first_timed:
            continue
        name = e["name"][: -len("_kernel_time")]
        totals[name] += e["dur"]
        ops[name] = e.get("args", {}).get("op_name", "?")
    return {name: (ops[name], us / steps) for name, us in totals.items()}


def matmul_peak_gflops(threads: int, size: int = 1024, repeats: int = 20) -> float:
    """GFLOP/s of a [size, size] @ [size, size] float32 MatMul in onnxruntime on ``threads``
    threads (median of ``repeats``): this machine's practical matmul peak."""
    import onnx
    import onnxruntime as ort
    from onnx import TensorProto, helper

    g = helper.make_graph([helper.make_node("MatMul", ["a", "b"], ["c"])], "peak",
                          [helper.make_tensor_value_info(n, TensorProto.FLOAT, [size, size]) for n in "ab"],
                          [helper.make_tensor_value_info("c", TensorProto.FLOAT, [size, size])])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 18)])
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    sess = ort.InferenceSession(m.SerializeToString(), so, providers=["CPUExecutionProvider"])
    a = np.random.default_rng(1).random((size, size), np.float32)
    feeds = {"a": a, "b": a}
    sess.run(None, feeds)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sess.run(None, feeds)
        times.append(time.perf_counter() - t0)
    del onnx
    return 2 * size**3 / float(np.median(times)) / 1e9


def breakdown_table(stages: dict, cost: dict, timed: dict, peak_gflops: float) -> str:
    """The markdown table: per stage, kernel ms per step, share, FLOPs, gathered values, % of peak,
    and its three largest operator types."""
    ms = defaultdict(float)
    flops = defaultdict(int)
    gathered = defaultdict(int)
    by_op = defaultdict(lambda: defaultdict(float))
    ran = set()
    for name, (op, us) in timed.items():
        node = profiled_name(name, op, stages)
        ran.add(node)
        st = stages[node] if node else ("masker" if op in MASKER_OPS else "other")
        ms[st] += us / 1e3
        by_op[st][op] += us / 1e3
    for name, (op, f, g) in cost.items():
        # nodes on constants (the sampling tables) are folded at session start: count what runs
        if name in ran or op in ("Conv", "MatMul"):
            flops[stages[name]] += f
            gathered[stages[name]] += g
    total = sum(ms.values())
    lines = [f"kernel time {total:.1f} ms per step; matmul peak {peak_gflops:.1f} GFLOP/s", "",
             "| stage | ms per step | share | MFLOP | M values gathered | % of matmul peak "
             "| largest operator types (ms) |",
             "|---|---:|---:|---:|---:|---:|---|"]
    for st in STAGES:
        if ms[st] == 0 and flops[st] == 0:
            continue
        rate = flops[st] / (ms[st] / 1e3) / 1e9 if ms[st] else 0.0
        top = sorted(by_op[st].items(), key=lambda kv: -kv[1])[:3]
        ops = ", ".join(f"{op} {t:.2f}" for op, t in top)
        lines.append(f"| {st} | {ms[st]:.2f} | {ms[st] / total:.0%} | {flops[st] / 1e6:.1f} | "
                     f"{gathered[st] / 1e6:.2f} | {100 * rate / peak_gflops:.0f} % | {ops} |")
    op_ms = defaultdict(float)
    for op, us in timed.values():
        op_ms[op] += us / 1e3
    lines += ["", "| operator type | ms per step | share |", "|---|---:|---:|"]
    for op, t in sorted(op_ms.items(), key=lambda kv: -kv[1])[:8]:
        lines.append(f"| {op} | {t:.2f} | {t / total:.0%} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", type=Path, default=CHECKPOINT, help="default: the shipped cart-0.4's")
    ap.add_argument("--settings", type=json.loads, default=None,
                    help="fast search settings as JSON (default: the profile's, as shipped)")
    ap.add_argument("--steps", type=int, default=50, help="profiled steps (default: %(default)s)")
    ap.add_argument("--warmup", type=int, default=10, help="unprofiled steps first (default: %(default)s)")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default: %(default)s)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the scoped graph at this path")
    ap.add_argument("--previous-session", action="store_true",
                    help="the previous release's session settings (workers spinning) instead of the SDK's")
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        path = args.keep or Path(tmp) / "scoped.onnx"
        scoped_export(args.checkpoint, path, args.settings)
        stages, cost = node_stages(path)
        peak = matmul_peak_gflops(args.threads)
        old = args.previous_session
        timed = profile_nodes(path, args.steps, args.warmup, args.threads, spinning=old)
        peak = max(peak, matmul_peak_gflops(args.threads))  # before and after: the better of two
    how = "previous session settings" if args.previous_session else "the SDK's session settings"
    print(f"{args.checkpoint.name}, fast search {args.settings or '(profile default)'}, {args.steps} steps, "
          f"{args.threads} threads, {how}\n")
    print(breakdown_table(stages, cost, timed, peak))
    return 0


if __name__ == "__main__":
    sys.exit(main())
