'use strict';
// Radar odometry from Oxford-layout sweep PNGs with a radar-odom sweep-form ONNX file, on onnxruntime-node.
//
//   node sweep_odometry.js MODEL.onnx SWEEP.png... [--range-resolution-m 0.0432] [--range-offset-m 0] [--threads N]
//                          [--time STEPS [--warmup W]]
//
// MODEL.onnx: `radar-odom export cart-0.4 --form sweep` (docs/sweep-form.md). Prints one JSON line per sweep:
// {"sweep": name, "pose": [x m, y m, yaw rad] | null, "covariance": [9 numbers] | null}; the pose is the sweep's
// in the previous sweep's frame (Oxford convention), null for the first. The graph's own poses: the Python
// SDK's RadarOdometer fuses them with a motion prior by default (motion_prior=False gives these).
//
// --time STEPS: the step time instead. The sweeps are read once, then W untimed steps (default 10) and STEPS timed
// ones run over them cycled, the state chained; a step is the sweep's tensors and one run, from the sweep in memory
// to the pose (as benchmarks/sweep_form.py times the Python SDK's). Prints one JSON line:
// {"steps": STEPS, "threads": N, "median_ms": m, "p90_ms": p, "step_ms": [every timed step]}.
const fs = require('fs');
const path = require('path');
const { PNG } = require('pngjs');
const ort = require('onnxruntime-node');

const ENCODER_SIZE = 5600; // encoder counts per turn (Navtech CTS350-X, the Oxford layout)
const HEADER_BYTES = 11; // per row: int64 µs timestamp, uint16 encoder count, uint8 valid (255), then the bins
const VALID_BYTE = 255;

function parseArgs(argv) {
  const opts = { rangeResolutionM: 0.0432, rangeOffsetM: 0.0, threads: 1, time: 0, warmup: 10, files: [] };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    if (a === '--range-resolution-m') opts.rangeResolutionM = Number(argv[++i]);
    else if (a === '--range-offset-m') opts.rangeOffsetM = Number(argv[++i]);
    else if (a === '--threads') opts.threads = Number(argv[++i]);
    else if (a === '--time') opts.time = Number(argv[++i]);
    else if (a === '--warmup') opts.warmup = Number(argv[++i]);
    else opts.files.push(a);
  }
  const whole = (n, least) => Number.isInteger(n) && n >= least;
  if (opts.files.length < 2 || !(opts.rangeResolutionM > 0) || !Number.isFinite(opts.rangeOffsetM) ||
      !whole(opts.threads, 1) || !whole(opts.time, 0) || !whole(opts.warmup, 0)) {
    throw new Error('usage: node sweep_odometry.js MODEL.onnx SWEEP.png... [--range-resolution-m M] ' +
                    '[--range-offset-m M] [--threads N ≥ 1] [--time STEPS ≥ 1 [--warmup W ≥ 0]]');
  }
  return opts;
}

// One Oxford-layout sweep: power float32[A*B] in [0, 1] (value / 255, dropped rows zero) and azimuths
// float32[A] (count / 5600 * 2π; a dropped row's, whose count may be garbage, interpolated by row index).
function readOxfordSweep(file) {
  const png = PNG.sync.read(fs.readFileSync(file));
  if (png.depth !== 8 || png.colorType !== 0) {
    throw new Error(`${file}: an Oxford sweep is an 8-bit greyscale PNG (depth ${png.depth}, colour type ${png.colorType})`);
  }
  const rows = png.height;
  const bins = png.width - HEADER_BYTES;
  const byte = (r, c) => png.data[(r * png.width + c) * 4]; // pngjs decodes to RGBA: grey is in every channel
  const power = new Float32Array(rows * bins);
  const azimuths = new Float64Array(rows);
  const valid = [];
  for (let r = 0; r < rows; r++) {
    valid.push(byte(r, 10) === VALID_BYTE);
    azimuths[r] = (byte(r, 8) | (byte(r, 9) << 8)) * (2 * Math.PI / ENCODER_SIZE);
    if (!valid[r]) continue;
    for (let b = 0; b < bins; b++) power[r * bins + b] = byte(r, HEADER_BYTES + b) / 255;
  }
  const good = valid.flatMap((v, r) => (v ? [r] : []));
  if (good.length < 2) throw new Error(`${file}: fewer than two valid azimuth rows`);
  const step = (azimuths[good[good.length - 1]] - azimuths[good[0]]) / (good[good.length - 1] - good[0]);
  for (let r = 0, k = 0; r < rows; r++) {
    while (k + 1 < good.length && good[k + 1] <= r) k++;
    if (valid[r]) continue;
    const a = good[k];
    const b = good[Math.min(k + 1, good.length - 1)];
    azimuths[r] = r < good[0] || r > b || a === b
      ? azimuths[r < good[0] ? good[0] : a] + step * (r - (r < good[0] ? good[0] : a))
      : azimuths[a] + (azimuths[b] - azimuths[a]) * (r - a) / (b - a);
  }
  return { power, azimuths: Float32Array.from(azimuths), rows, bins };
}

// One step: the sweep's tensors and one run of the graph with the previous state.
function step(session, sweep, opts, state) {
  return session.run({
    power: new ort.Tensor('float32', sweep.power, [sweep.rows, sweep.bins]),
    azimuths_rad: new ort.Tensor('float32', sweep.azimuths, [sweep.rows]),
    range_resolution_m: new ort.Tensor('float32', Float32Array.of(opts.rangeResolutionM), [1]),
    range_offset_m: new ort.Tensor('float32', Float32Array.of(opts.rangeOffsetM), [1]),
    prev_state: state,
  });
}

// The value below which a fraction q of the sorted values lies, linearly interpolated (numpy's default percentile).
function quantile(sorted, q) {
  const at = (sorted.length - 1) * q;
  const lo = Math.floor(at);
  const hi = Math.min(lo + 1, sorted.length - 1);
  return sorted[lo] + (sorted[hi] - sorted[lo]) * (at - lo);
}

async function timeSteps(session, sweeps, opts, state) {
  const sweepData = sweeps.map(readOxfordSweep);
  const stepMs = [];
  for (let i = 0; i < opts.warmup + opts.time; i++) {
    const t0 = process.hrtime.bigint();
    state = (await step(session, sweepData[i % sweepData.length], opts, state)).state;
    if (i >= opts.warmup) stepMs.push(Number(process.hrtime.bigint() - t0) / 1e6);
  }
  const sorted = [...stepMs].sort((a, b) => a - b);
  console.log(JSON.stringify({
    steps: opts.time, threads: opts.threads, median_ms: quantile(sorted, 0.5), p90_ms: quantile(sorted, 0.9),
    step_ms: stepMs,
  }));
}

async function main() {
  const opts = parseArgs(process.argv.slice(2));
  const [modelPath, ...sweeps] = opts.files;
  // the Python SDK's session settings (radar_odom.onnx_model.session_options): one inter-op worker, sequential,
  // and intra-op workers that sleep between operators rather than spin (a spinning one holds a core it does not use)
  const session = await ort.InferenceSession.create(modelPath, {
    intraOpNumThreads: opts.threads, interOpNumThreads: 1, executionMode: 'sequential',
    extra: { 'session.intra_op.allow_spinning': '0' },
  });
  const stateInput = session.inputMetadata.find((m) => m.name === 'prev_state');
  if (!stateInput || session.inputNames[0] !== 'power') {
    throw new Error(`${modelPath}: not a sweep-form model (inputs ${session.inputNames}); export one with ` +
                    '`radar-odom export NAME --form sweep`');
  }
  let state = new ort.Tensor('float32', new Float32Array(stateInput.shape.reduce((a, b) => a * b, 1)),
                             stateInput.shape);
  if (opts.time > 0) return timeSteps(session, sweeps, opts, state);
  for (let i = 0; i < sweeps.length; i++) {
    const out = await step(session, readOxfordSweep(sweeps[i]), opts, state);
    state = out.state; // the first sweep's pose is against an empty state: only its state is kept
    const first = i === 0;
    console.log(JSON.stringify({
      sweep: path.basename(sweeps[i]),
      pose: first ? null : Array.from(out.pose.data),
      covariance: first ? null : Array.from(out.covariance.data),
    }));
  }
}

main().catch((err) => {
  console.error(`error: ${err.message}`);
  process.exit(1);
});
