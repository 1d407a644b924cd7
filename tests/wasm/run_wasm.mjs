// Run a Python script on the official 32-bit MicroPython (WebAssembly port) under Node.js.
//
// Usage: node tests/wasm/run_wasm.mjs [--heap BYTES] [--step NAME] [HOSTDIR=/WASMDIR ...] SCRIPT.py
//
// The port has no host filesystem: every *.py and *.json under each HOSTDIR is copied into
// the in-memory FS at WASMDIR, which is put on sys.path, before SCRIPT runs.
// Python's stdout goes to stdout; an uncaught Python exception is printed to
// stderr and gives exit code 1. Callers must run this under a timeout.
//
// --step NAME: after SCRIPT, call the Python function NAME from here until it returns 0 (or
// an exception); when it returns 2, call gc.collect() from here before calling it again.
// This port's gc.collect() inside a running script only marks a collection as wanted; it
// runs when the outermost call from JavaScript returns (MICROPY_GC_SPLIT_HEAP_AUTO: the
// scanner cannot see pointers held in Wasm locals, so it collects only where there are
// none). Each of these calls is such a top-level call, so a step that returns 2 is followed
// by a real collection before the next one (tests/run_micropython.py's STEP_DRIVER).
import { readFileSync, readdirSync, statSync } from "node:fs";
import { join } from "node:path";
import { fileURLToPath } from "node:url";

const here = fileURLToPath(new URL(".", import.meta.url));
const { loadMicroPython } = await import(
  join(here, "..", "..", "node_modules", "@micropython", "micropython-webassembly-pyscript", "micropython.mjs"));

let heap = 1 << 21;
const mounts = [];
let script = null;
let step = null;
const argv = process.argv.slice(2);
for (let i = 0; i < argv.length; i++) {
  if (argv[i] === "--heap") heap = parseInt(argv[++i], 10);
  else if (argv[i] === "--step") step = argv[++i];
  else if (argv[i].includes("=")) mounts.push(argv[i].split("="));
  else script = argv[i];
}
if (!script) {
  process.stderr.write("usage: run_wasm.mjs [--heap BYTES] [--step NAME] [HOSTDIR=/WASMDIR ...] SCRIPT.py\n");
  process.exit(2);
}

const mp = await loadMicroPython({
  heapsize: heap,
  linebuffer: true,
  stdout: (line) => process.stdout.write(line + "\n"),
  stderr: (line) => process.stderr.write(line + "\n"),
});

function mkdirs(path) {
  let cur = "";
  for (const part of path.split("/").filter(Boolean)) {
    cur += "/" + part;
    try { mp.FS.mkdir(cur); } catch (e) { /* exists */ }
  }
}

function copyTree(hostDir, wasmDir) {
  mkdirs(wasmDir);
  for (const name of readdirSync(hostDir)) {
    const h = join(hostDir, name);
    if (statSync(h).isDirectory()) {
      if (name !== "__pycache__") copyTree(h, wasmDir + "/" + name);
    } else if (name.endsWith(".py") || name.endsWith(".json")) {
      mp.FS.writeFile(wasmDir + "/" + name, readFileSync(h));
    }
  }
}

const paths = [];
for (const [hostDir, wasmDir] of mounts) {
  copyTree(hostDir, wasmDir);
  paths.push(wasmDir);
}
mp.runPython("import sys\nsys.path[0:0] = " + JSON.stringify(paths) + "\n");
try {
  mp.runPython(readFileSync(script, "utf8"));
  if (step !== null) {
    const fn = mp.globals.get(step);
    const collect = mp.pyimport("gc").collect;
    for (;;) {
      const r = fn();
      if (!r) break;
      if (r === 2) collect();
    }
  }
} catch (e) {
  process.stderr.write(String(e.message || e) + "\n");
  process.exitCode = 1;
}
