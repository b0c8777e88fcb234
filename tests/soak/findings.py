#!/usr/bin/env python3
"""Replays the denial-of-service findings against fresh servers and reports, for each,
the answer, how long it took and the server's peak RSS (`VmHWM`).

Each finding gets a server of its own (started like the soak test's, on a free loopback
port), so that every peak belongs to one repro. The inputs are made here, in memory:
wide frames, a grade envelope of 1.2 M pixels, a scene of 700 k invalid objects, a
16-bit RGBA PNG of 4096², coincident spheres for /v1/trace, a scene whose every ray
branches, invented HTTP methods, idle sockets. Loopback only, bounded in time.

usage: findings.py --binary target/release/raytile [--only NAME ...] [--memory-bytes N]
"""

from __future__ import annotations

import argparse
import concurrent.futures
import http.client
import json
import resource
import socket
import struct
import sys
import time
import zlib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import soak  # noqa: E402  (the server start and /proc reading are shared)

LECTURE = json.loads((soak.SCENES / "lecture.json").read_text())


def scene(width: int, height: int, **more) -> bytes:
    doc = json.loads(json.dumps(LECTURE))
    doc["image"] = {"width": width, "height": height, **more.pop("image", {})}
    doc.update(more)
    return compact(doc)


def compact(doc) -> bytes:
    """JSON without spaces, as the findings' bodies were sent (under the 16 MiB limit)."""
    return json.dumps(doc, separators=(",", ":")).encode()


def post(host: str, port: int, path: str, body: bytes, ctype: str = "application/json",
         accept: str = "*/*", timeout: float = 600) -> tuple[int, int, float]:
    """Status, bytes read and seconds of one request, reading the answer as it comes."""
    start = time.monotonic()
    conn = http.client.HTTPConnection(host, port, timeout=timeout)
    try:
        conn.request("POST", path, body=body, headers={"Content-Type": ctype, "Accept": accept})
        resp = conn.getresponse()
        n, head = 0, b""
        try:
            while chunk := resp.read(1 << 16):
                n += len(chunk)
                head = head or chunk[:2048]
        except http.client.IncompleteRead as e:
            n += len(e.partial)
            return -resp.status, n, time.monotonic() - start, ""
        kind = ""
        if resp.getheader("Content-Type", "").startswith("application/problem+json"):
            try:
                kind = json.loads(head)["type"].rsplit("/", 1)[-1]
            except (ValueError, KeyError):
                kind = "?"
        return resp.status, n, time.monotonic() - start, kind
    finally:
        conn.close()


def png16_rgba(width: int, height: int) -> bytes:
    """A 16-bit RGBA PNG, opaque, of a pattern that compresses well (the body limit)."""
    row = bytearray(b"\x00")
    for u in range(width):
        row += struct.pack(">HHHH", (u % 16) * 4096, 0x8000, 0x1234, 0xFFFF)
    raw = bytes(row) * height

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", width, height, 16, 6, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
            + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def concurrently(n: int, f):
    with concurrent.futures.ThreadPoolExecutor(n) as pool:
        return list(pool.map(lambda _: f(), range(n)))


def describe(results) -> str:
    statuses = sorted({f"{r[0]} {r[3]}".strip() for r in results})
    took = max(r[2] for r in results)
    return f"status {', '.join(statuses)}, {sum(r[1] for r in results)} bytes, {took:.2f} s"


# Each finding: a name and a function of (host, port) returning a one-line outcome.
def wide_hits(fmt: str, width: int, height: int):
    accept = {"json": "application/json", "npy": "application/x-npy"}[fmt]
    return lambda h, p: describe([post(h, p, "/v1/hits", scene(width, height), accept=accept)])


def wide_render(h, p):
    return describe([post(h, p, "/v1/render", scene(16777216, 1), accept="image/png")])


def grade_envelope(copies: int):
    # 1.1 M misses: 15 MB, just under the body limit.
    body = compact({"scene": json.loads(scene(1100, 1000)),
                    "submission": [[{"hit": False}] * 1100] * 1000})

    def run(h, p):
        return f"{len(body) >> 20} MiB each: " + describe(
            concurrently(copies, lambda: post(h, p, "/v1/grade", body)))
    return run


def invalid_objects(copies: int):
    doc = json.loads(scene(5, 5))
    doc["objects"] = [{"shape": "teapot"}] * 700_000
    body = compact(doc)

    def run(h, p):
        return f"{len(body) >> 20} MiB each: " + describe(
            concurrently(copies, lambda: post(h, p, "/v1/render", body, accept="image/png")))
    return run


def png16_submission(h, p):
    image = png16_rgba(4096, 4096)
    body, ctype = soak.multipart({
        "scene": ("scene.json", scene(4096, 4096), "application/json"),
        "submission": ("student.png", image, "image/png"),
    })
    return f"{len(image) >> 20} MiB PNG: " + describe([post(h, p, "/v1/grade", body, ctype)])


def stalled_readers(h, p):
    held = []
    for _ in range(10):
        s = socket.create_connection((h, p))
        body = scene(4096, 4096)
        s.sendall(b"POST /v1/hits HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                  b"Accept: application/x-ndjson\r\n" + f"Content-Length: {len(body)}\r\n\r\n".encode() + body)
        held.append(s)
    time.sleep(2)
    r = post(h, p, "/v1/render", scene(64, 64), accept="image/png", timeout=120)
    for s in held:
        s.close()
    return f"64×64 render beside ten stalled 4096² hits: status {r[0]} in {r[2]:.3f} s"


def coincident_spheres(n: int, material: dict | None, query: str):
    doc = json.loads(scene(8, 8))
    sphere = {"shape": "sphere"}
    if material:
        doc["materials"] = {"m": material}
        sphere["material"] = "m"
    doc["objects"] = [sphere] * n
    body = compact(doc)

    def run(h, p):
        return f"{len(body) >> 20} MiB scene: " + describe([post(h, p, "/v1/trace?" + query, body)])
    return run


def branching(h, p):
    doc = {"version": 1, "image": {"width": 1024, "height": 1024, "samples": 8}, "max_depth": 10,
           "camera": {"focal_length": 1},
           "materials": {"m": {"diffuse": [0.1, 0.1, 0.1], "mirror": [0.5, 0.5, 0.5], "transmission": [0.5, 0.5, 0.5], "ior": 1.5}},
           "objects": [{"shape": "sphere", "material": "m", "transform": [{"scale": 100}]}],
           "lights": [{"type": "point", "position": [0, -4, 0], "colour": [1, 1, 1]}]}
    body = compact(doc)
    return f"{len(body)}-byte scene: " + describe([post(h, p, "/v1/render", body, accept="image/png")])


def invented_methods(h, p):
    for i in range(20000):
        s = socket.create_connection((h, p))
        s.sendall(f"M{i:05d}X /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n".encode())
        while s.recv(4096):
            pass
        s.close()
    conn = http.client.HTTPConnection(h, p, timeout=30)
    conn.request("GET", "/metrics")
    text = conn.getresponse().read().decode()
    series = sum(1 for line in text.splitlines() if line.startswith("raytile_http_requests_total"))
    return f"/metrics after 20 000 invented methods: {len(text)} bytes, {series} request-count series"


def idle_sockets(h, p):
    held = [socket.create_connection((h, p)) for _ in range(300)]
    start = time.monotonic()
    try:
        conn = http.client.HTTPConnection(h, p, timeout=30)
        conn.request("GET", "/healthz")
        status = conn.getresponse().status
    except OSError as e:
        status = f"error {e}"
    took = time.monotonic() - start
    for s in held:
        s.close()
    return f"/healthz beside 300 idle sockets (256 descriptors): {status} in {took * 1000:.1f} ms"


FINDINGS = {
    "1-hits-json-4000000x1": wide_hits("json", 4_000_000, 1),
    "1-hits-npy-4000000x1": wide_hits("npy", 4_000_000, 1),
    "1-hits-json-2000000x1": wide_hits("json", 2_000_000, 1),
    "1-hits-json-843137x5": wide_hits("json", 843_137, 5),
    "1-render-16777216x1": wide_render,
    "2-grade-envelope-x1": grade_envelope(1),
    "2-grade-envelope-x4": grade_envelope(4),
    "2-invalid-objects-x4": invalid_objects(4),
    "2-png16-4096": png16_submission,
    "3-stalled-readers": stalled_readers,
    "4-trace-300k-bvh": coincident_spheres(300_000, None, "u=4&v=4&candidates=bvh&max_rays=1024&max_triangles=1024"),
    "4-trace-200k-glass": coincident_spheres(
        200_000, {"diffuse": [0.1, 0.1, 0.1], "mirror": [0.5, 0.5, 0.5], "transmission": [0.5, 0.5, 0.5], "ior": 1.5}, "u=4&v=4&candidates=bvh"),
    "5-branching": branching,
    "6-invented-methods": invented_methods,
    "7-idle-sockets": idle_sockets,
}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--binary", required=True)
    p.add_argument("--only", nargs="*", help="finding names (prefixes) to replay")
    p.add_argument("--memory-bytes", type=int, default=768 * 1024 * 1024)
    p.add_argument("--server-arg", action="append", default=[])
    args = p.parse_args()
    server_args = argparse.Namespace(
        binary=args.binary, max_renders=2, threads=2, queue=8, memory_bytes=args.memory_bytes,
        stall_seconds=15, server_arg=args.server_arg)
    failed = 0
    for name, run in FINDINGS.items():
        if args.only and not any(name.startswith(o) for o in args.only):
            continue
        limit = 256 if name.startswith("7-") else None
        old = resource.getrlimit(resource.RLIMIT_NOFILE)
        if limit:
            resource.setrlimit(resource.RLIMIT_NOFILE, (limit, old[1]))
        try:
            server, host, port = soak.start_server(server_args)
        finally:
            resource.setrlimit(resource.RLIMIT_NOFILE, old)
        try:
            outcome = run(host, port)
        except Exception as e:  # a repro that cannot even be replayed is a failure
            outcome = f"ERROR {type(e).__name__}: {e}"
            failed += 1
        alive = server.poll() is None
        hwm = soak.proc_status(server.pid, "VmHWM") if alive else 0
        server.terminate()
        server.wait(60)
        print(f"{name:24} VmHWM {hwm / 2**20:7.1f} MiB  {'' if alive else 'SERVER DIED  '}{outcome}", flush=True)
        failed += not alive
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
