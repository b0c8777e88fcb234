#!/usr/bin/env python3
"""Soak test: a mixed, hostile load at twice the server's capacity, on loopback.

Starts `raytile serve` on a free loopback port with the given limits, then runs
2 × (max-renders + queue) clients for DURATION seconds. Each client picks, at random,
a small or a large render, hit data (NPY, NDJSON, JSON), a grade (a correct and a wrong
PNG), a validation, an invalid body, a slow reader that reads a big response a little at
a time, a client that never reads, or one that disconnects half-way. Meanwhile a separate
process asks `/healthz` every 100 ms, and the server's resident memory is sampled.

It passes when:
- every answer that came back is 2xx, 4xx or 503 (never another 5xx, never a response
  cut short for a client that was reading);
- the server's peak RSS (`VmHWM` in /proc/PID/status) stays under `--memory-bytes`;
- `/healthz` answered every probe within `--healthz-ms` (100 ms);
- the server is still alive at the end and exits cleanly on SIGTERM.

Everything is bounded: the duration, each request's timeout, the number of clients.
Only the standard library is used, so any Python 3.8+ runs it.

usage: soak.py --binary target/release/raytile [--duration 60] [--memory-bytes N] ...
"""

from __future__ import annotations

import argparse
import http.client
import json
import multiprocessing
import os
import random
import re
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import zlib
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCENES = ROOT / "scenes"


def load_scene(name: str, width: int, height: int) -> dict:
    scene = json.loads((SCENES / name).read_text())
    scene["image"]["width"] = width
    scene["image"]["height"] = height
    return scene


def png(width: int, height: int, rgb: tuple[int, int, int]) -> bytes:
    """A plain 8-bit RGB PNG of one colour (for a wrong submission)."""
    row = b"\x00" + bytes(rgb) * width
    raw = row * height

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def multipart(parts: dict[str, tuple[str, bytes, str]]) -> tuple[bytes, str]:
    boundary = "soak%016x" % random.getrandbits(64)
    out = bytearray()
    for name, (filename, data, ctype) in parts.items():
        out += (f"--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"; "
                f"filename=\"{filename}\"\r\nContent-Type: {ctype}\r\n\r\n").encode()
        out += data + b"\r\n"
    out += f"--{boundary}--\r\n".encode()
    return bytes(out), f"multipart/form-data; boundary={boundary}"


class Tally:
    """What happened, by request kind and outcome; shared by the client threads."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.outcomes: Counter[tuple[str, str]] = Counter()
        self.failures: list[str] = []
        self.latency: dict[str, list[float]] = {}

    def record(self, kind: str, outcome: str, seconds: float, bad: str | None = None) -> None:
        with self.lock:
            self.outcomes[(kind, outcome)] += 1
            self.latency.setdefault(kind, []).append(seconds)
            if bad is not None and len(self.failures) < 50:
                self.failures.append(f"{kind}: {bad}")


def allowed(status: int) -> bool:
    return 200 <= status < 300 or 400 <= status < 500 or status == 503


class Load:
    def __init__(self, host: str, port: int, args: argparse.Namespace) -> None:
        self.host, self.port, self.args = host, port, args
        self.tally = Tally()
        small = load_scene("lecture.json", 64, 64)
        self.small = json.dumps(small).encode()
        self.large = json.dumps(load_scene("showcase.json", args.large, args.large)).encode()
        self.hits = json.dumps(load_scene("lecture.json", 256, 256)).encode()
        self.big_hits = json.dumps(load_scene("lecture.json", 2048, 2048)).encode()
        self.wrong_png = png(64, 64, (255, 0, 255))
        self.correct_png = b""
        self.invalid = [
            b"{not json",
            b'{"image": {"width": 5, "height": 5, "width": 6}}',
            json.dumps({"image": {"width": -3, "height": 5}}).encode(),
            json.dumps({**small, "objects": [{"shape": "teapot"}] * 200}).encode(),
            json.dumps({**small, "image": {"width": 4000000, "height": 4000000}}).encode(),
            json.dumps({**small, "max_depth": 1e9}).encode(),
            b"[]",
            b"",
        ]

    def connection(self) -> http.client.HTTPConnection:
        return http.client.HTTPConnection(self.host, self.port, timeout=self.args.request_timeout)

    def request(self, kind: str, method: str, path: str, body: bytes, headers: dict[str, str]) -> None:
        start = time.monotonic()
        conn = self.connection()
        try:
            conn.request(method, path, body=body, headers=headers)
            resp = conn.getresponse()
            data = resp.read()
            took = time.monotonic() - start
            if not allowed(resp.status):
                self.tally.record(kind, str(resp.status), took, f"status {resp.status}: {data[:200]!r}")
                return
            if resp.status == 200 and headers.get("Accept") == "image/png" and not data.startswith(b"\x89PNG"):
                self.tally.record(kind, "not-png", took, "a 200 render that is not a PNG")
                return
            self.tally.record(kind, str(resp.status), took)
        except (http.client.HTTPException, OSError) as e:
            self.tally.record(kind, "cut", time.monotonic() - start, f"{type(e).__name__}: {e}")
        finally:
            conn.close()

    def raw(self, path: str, body: bytes, accept: str) -> socket.socket:
        s = socket.create_connection((self.host, self.port), timeout=self.args.request_timeout)
        head = (f"POST {path} HTTP/1.1\r\nHost: {self.host}\r\nContent-Type: application/json\r\n"
                f"Accept: {accept}\r\nContent-Length: {len(body)}\r\n\r\n").encode()
        s.sendall(head + body)
        return s

    # The kinds of client, each one request.
    def render_small(self) -> None:
        self.request("render-small", "POST", "/v1/render", self.small,
                     {"Content-Type": "application/json", "Accept": "image/png"})

    def render_large(self) -> None:
        self.request("render-large", "POST", "/v1/render", self.large,
                     {"Content-Type": "application/json", "Accept": "image/png"})

    def hit_data(self) -> None:
        accept = random.choice(["application/x-npy", "application/x-ndjson", "application/json"])
        self.request("hits", "POST", "/v1/hits", self.hits,
                     {"Content-Type": "application/json", "Accept": accept})

    def grade(self) -> None:
        submission = self.correct_png if self.correct_png and random.random() < 0.5 else self.wrong_png
        body, ctype = multipart({
            "scene": ("scene.json", self.small, "application/json"),
            "submission": ("student.png", submission, "image/png"),
        })
        self.request("grade", "POST", "/v1/grade", body, {"Content-Type": ctype})

    def validate(self) -> None:
        body = random.choice([self.small, random.choice(self.invalid)])
        self.request("validate", "POST", "/v1/validate", body, {"Content-Type": "application/json"})

    def invalid_body(self) -> None:
        path = random.choice(["/v1/render", "/v1/hits", "/v1/trace?u=1&v=1"])
        self.request("invalid", "POST", path, random.choice(self.invalid),
                     {"Content-Type": "application/json", "Accept": "*/*"})

    def oversized_claim(self) -> None:
        """Claims a body far over the limit and sends a little: refused, never read whole."""
        start = time.monotonic()
        try:
            s = socket.create_connection((self.host, self.port), timeout=self.args.request_timeout)
            with s:
                s.sendall(b"POST /v1/render HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                          b"Content-Length: 1000000000\r\n\r\n{\"image\":")
                status = read_status(s)
            outcome = str(status) if status is not None else "closed"
            bad = None if status is None or allowed(status) else f"status {status}"
            self.tally.record("oversized", outcome, time.monotonic() - start, bad)
        except OSError as e:
            self.tally.record("oversized", "closed", time.monotonic() - start) if is_reset(e) else \
                self.tally.record("oversized", "error", time.monotonic() - start, str(e))

    def slow_reader(self) -> None:
        """Reads a big response a kilobyte at a time for a few seconds, then leaves."""
        start = time.monotonic()
        try:
            with self.raw("/v1/hits", self.big_hits, "application/x-ndjson") as s:
                status = read_status(s)
                if status is not None and not allowed(status):
                    self.tally.record("slow-reader", str(status), time.monotonic() - start, f"status {status}")
                    return
                if status != 200:
                    self.tally.record("slow-reader", str(status), time.monotonic() - start)
                    return
                s.settimeout(0.5)
                until = time.monotonic() + random.uniform(1, 5)
                while time.monotonic() < until:
                    try:
                        if not s.recv(1024):
                            break
                    except socket.timeout:
                        continue
                    time.sleep(0.05)
            self.tally.record("slow-reader", str(status), time.monotonic() - start)
        except OSError as e:
            self.tally.record("slow-reader", "closed", time.monotonic() - start,
                              None if is_reset(e) else str(e))

    def never_reads(self) -> None:
        """Asks for a big response and holds the socket without reading, then leaves."""
        start = time.monotonic()
        try:
            with self.raw("/v1/hits", self.big_hits, "application/x-npy"):
                time.sleep(random.uniform(2, 8))
            self.tally.record("never-reads", "left", time.monotonic() - start)
        except OSError as e:
            self.tally.record("never-reads", "closed", time.monotonic() - start,
                              None if is_reset(e) else str(e))

    def disconnect(self) -> None:
        """Sends half a body and leaves, or leaves as the answer starts."""
        start = time.monotonic()
        try:
            if random.random() < 0.5:
                s = socket.create_connection((self.host, self.port), timeout=self.args.request_timeout)
                with s:
                    s.sendall(b"POST /v1/render HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                              + f"Content-Length: {len(self.large)}\r\n\r\n".encode()
                              + self.large[: len(self.large) // 2])
            else:
                with self.raw("/v1/render", self.large, "image/png") as s:
                    s.recv(100)
            self.tally.record("disconnect", "left", time.monotonic() - start)
        except OSError as e:
            self.tally.record("disconnect", "closed", time.monotonic() - start,
                              None if is_reset(e) else str(e))

    def client(self, stop_at: float, seed: int) -> None:
        rng = random.Random(seed)
        kinds = [
            (self.render_small, 24), (self.render_large, 6), (self.hit_data, 12),
            (self.grade, 10), (self.validate, 10), (self.invalid_body, 10),
            (self.oversized_claim, 3), (self.slow_reader, 4), (self.never_reads, 3),
            (self.disconnect, 4),
        ]
        funcs, weights = zip(*kinds)
        while time.monotonic() < stop_at:
            rng.choices(funcs, weights)[0]()

    def fetch_correct_png(self) -> None:
        conn = self.connection()
        try:
            conn.request("POST", "/v1/render", body=self.small,
                         headers={"Content-Type": "application/json", "Accept": "image/png"})
            resp = conn.getresponse()
            data = resp.read()
            if resp.status != 200:
                raise SystemExit(f"soak: the first render answered {resp.status}: {data[:300]!r}")
            self.correct_png = data
        finally:
            conn.close()


def read_status(s: socket.socket) -> int | None:
    """The status of the answer on `s`, or None when the server closed without one."""
    head = b""
    while b"\r\n" not in head:
        part = s.recv(256)
        if not part:
            return None
        head += part
    m = re.match(rb"HTTP/1\.[01] (\d{3})", head)
    return int(m.group(1)) if m else None


def is_reset(e: OSError) -> bool:
    return isinstance(e, (ConnectionResetError, BrokenPipeError, ConnectionAbortedError, socket.timeout))


def probe_health(host: str, port: int, stop_at: float, results) -> None:
    """In its own process (no shared interpreter lock with the load): asks /healthz
    every 100 ms and sends back each probe's latency, or None for a failed probe."""
    latencies = []
    while time.monotonic() < stop_at:
        start = time.monotonic()
        try:
            conn = http.client.HTTPConnection(host, port, timeout=5)
            conn.request("GET", "/healthz")
            resp = conn.getresponse()
            resp.read()
            conn.close()
            latencies.append(time.monotonic() - start if resp.status == 200 else None)
        except (http.client.HTTPException, OSError):
            latencies.append(None)
        time.sleep(max(0.0, 0.1 - (time.monotonic() - start)))
    results.put(latencies)


def proc_status(pid: int, field: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise KeyError(field)


def start_server(args: argparse.Namespace) -> tuple[subprocess.Popen, str, int]:
    cmd = [args.binary, "serve", "--addr", "127.0.0.1:0",
           "--max-renders", str(args.max_renders), "--threads", str(args.threads),
           "--queue", str(args.queue), "--memory-bytes", str(args.memory_bytes),
           "--stall-seconds", str(args.stall_seconds), *args.server_arg]
    env = {**os.environ, "RAYTILE_LOG_FORMAT": "text", "RUST_LOG": "warn,raytile=info"}
    server = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env, text=True)
    deadline = time.monotonic() + 60
    assert server.stdout is not None
    for line in server.stdout:
        m = re.search(r"listening on http://([0-9.]+):(\d+)", line)
        if m:
            # Keep draining the log so that the server never blocks on a full pipe.
            threading.Thread(target=lambda: [None for _ in server.stdout], daemon=True).start()
            return server, m.group(1), int(m.group(2))
        if time.monotonic() > deadline:
            break
    server.kill()
    raise SystemExit(f"soak: the server did not start: {' '.join(cmd)}")


def percentile(xs: list[float], p: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(p * len(xs)))] if xs else 0.0


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--binary", required=True, help="the raytile binary to run")
    p.add_argument("--duration", type=float, default=60, help="seconds of load [60]")
    p.add_argument("--max-renders", type=int, default=2)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--queue", type=int, default=8)
    p.add_argument("--memory-bytes", type=int, default=768 * 1024 * 1024,
                   help="the server's budget, and the bound on its peak RSS [768 MiB]")
    p.add_argument("--stall-seconds", type=float, default=5)
    p.add_argument("--large", type=int, default=512, help="the large render's width and height [512]")
    p.add_argument("--healthz-ms", type=float, default=100, help="slowest /healthz allowed [100]")
    p.add_argument("--request-timeout", type=float, default=120)
    p.add_argument("--clients", type=int, help="default: twice max-renders + queue")
    p.add_argument("--server-arg", action="append", default=[], help="one more argument for the server")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    random.seed(args.seed)
    clients = args.clients or 2 * (args.max_renders + args.queue)

    server, host, port = start_server(args)
    try:
        load = Load(host, port, args)
        load.fetch_correct_png()
        baseline = proc_status(server.pid, "VmRSS")
        stop_at = time.monotonic() + args.duration
        results: multiprocessing.Queue = multiprocessing.Queue()
        prober = multiprocessing.Process(target=probe_health, args=(host, port, stop_at, results))
        prober.start()
        threads = [threading.Thread(target=load.client, args=(stop_at, args.seed * 1000 + i), daemon=True)
                   for i in range(clients)]
        for t in threads:
            t.start()
        rss_samples = []
        while time.monotonic() < stop_at:
            rss_samples.append(proc_status(server.pid, "VmRSS"))
            time.sleep(0.25)
        for t in threads:
            t.join(args.request_timeout + 30)
        latencies = results.get(timeout=30)
        prober.join(10)
        alive = server.poll() is None
        hwm = proc_status(server.pid, "VmHWM") if alive else 0
    finally:
        if server.poll() is None:
            server.send_signal(signal.SIGTERM)
        try:
            code = server.wait(60)
        except subprocess.TimeoutExpired:
            server.kill()
            code = None

    ok = [x for x in latencies if x is not None]
    failed_probes = len(latencies) - len(ok)
    slow = [x for x in ok if x * 1000 > args.healthz_ms]
    tally = load.tally
    total = sum(tally.outcomes.values())

    print(f"soak: {args.duration:.0f} s, {clients} clients against --max-renders {args.max_renders} "
          f"--threads {args.threads} --queue {args.queue} --memory-bytes {args.memory_bytes}")
    print(f"requests: {total}")
    for kind in sorted({k for k, _ in tally.outcomes}):
        outcomes = ", ".join(f"{o}: {n}" for (k, o), n in sorted(tally.outcomes.items()) if k == kind)
        lat = tally.latency.get(kind, [])
        print(f"  {kind:13} {outcomes:40} median {percentile(lat, 0.5):.3f} s, max {max(lat, default=0):.3f} s")
    print(f"/healthz: {len(latencies)} probes, {failed_probes} failed, median {percentile(ok, 0.5) * 1000:.1f} ms, "
          f"p99 {percentile(ok, 0.99) * 1000:.1f} ms, max {max(ok, default=0) * 1000:.1f} ms, "
          f"{len(slow)} over {args.healthz_ms:.0f} ms")
    print(f"server memory: RSS at start {baseline / 2**20:.0f} MiB, highest sample "
          f"{max(rss_samples, default=0) / 2**20:.0f} MiB, VmHWM {hwm / 2**20:.0f} MiB "
          f"(budget {args.memory_bytes / 2**20:.0f} MiB)")
    print(f"server: {'alive at the end' if alive else 'DIED'}, exit code after SIGTERM {code}")

    problems = list(tally.failures)
    if not alive:
        problems.append("the server died during the soak")
    if code != 0:
        problems.append(f"the server exited with {code} after SIGTERM")
    if hwm >= args.memory_bytes:
        problems.append(f"peak RSS {hwm} bytes is not under the budget {args.memory_bytes}")
    if failed_probes:
        problems.append(f"{failed_probes} /healthz probes failed")
    if slow:
        problems.append(f"{len(slow)} /healthz probes took over {args.healthz_ms:.0f} ms")
    if not any(o == "200" for (k, o) in tally.outcomes if k == "render-small"):
        problems.append("no small render succeeded")
    for line in problems:
        print(f"FAIL {line}")
    print("soak: " + ("passed" if not problems else f"failed ({len(problems)} problems)"))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
