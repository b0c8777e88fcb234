#!/usr/bin/env python3
"""Submissions to a running raytile server: the first submission of an assignment (which
renders its references) against the next (which finds them cached), and submissions a
second with many clients at once.

    cargo build --release --locked
    python3 docs/bench/submissions.py --binary target/release/raytile
    python3 docs/bench/submissions.py --binary target/release/raytile \
        --database postgres://raytile_test:raytile_test@127.0.0.1:5432/raytile_test

It starts the server on a free port (with a fresh data folder, or the given PostgreSQL
database), pushes assignments of five 640 x 480 scenes (the shipped showcase, moved a
little for each scene and each round, so that every round's references are new), renders
each scene once through /v1/render as the student's submission, and times

- per round, the first submission (renders the five references) and a second one
  (another student; the references are cached), as the client sees them, end to end;
- then CLIENTS clients submitting at once, each as its own students, for SECONDS.

It prints the medians and the rate, and the server's reference cache counters. Only the
standard library is used.
"""

import argparse
import json
import os
import secrets
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TOKEN = "bench-" + secrets.token_hex(16)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def request(url, method="GET", body=None, headers=None, timeout=600):
    req = urllib.request.Request(url, data=body, method=method, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as res:
            return res.status, res.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def auth(extra=None):
    h = {"Authorization": "Bearer " + TOKEN}
    h.update(extra or {})
    return h


def scene(round_no, k):
    with open(os.path.join(ROOT, "scenes", "showcase.json")) as f:
        s = json.load(f)
    s["image"]["width"], s["image"]["height"] = 640, 480
    # A different background for every scene of every round: a different document.
    s["background"] = [0.01 * k, 0.002 * round_no, 0.05]
    return s


def multipart(student, files):
    boundary = "raytile-bench-" + secrets.token_hex(8)
    out = []
    out.append(
        f'--{boundary}\r\nContent-Disposition: form-data; name="student"\r\n\r\n'
        f"{student}\r\n".encode()
    )
    for name, png in files.items():
        out.append(
            f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"; '
            f'filename="{name}.png"\r\nContent-Type: image/png\r\n\r\n'.encode()
        )
        out.append(png)
        out.append(b"\r\n")
    out.append(f"--{boundary}--\r\n".encode())
    return b"".join(out), "multipart/form-data; boundary=" + boundary


class Server:
    def __init__(self, binary, database, threads):
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.data = tempfile.mkdtemp(prefix="raytile-bench-")
        env = dict(os.environ)
        env.update(
            {
                "RAYTILE_ADDR": f"127.0.0.1:{self.port}",
                "RAYTILE_DATA_DIR": self.data,
                "RAYTILE_ADMIN_TOKEN": TOKEN,
                "RAYTILE_SUBMISSIONS_PER_HOUR": "0",
                "RAYTILE_QUEUE": "64",
                "RAYTILE_LOG_FORMAT": "json",
                "RUST_LOG": "warn",
            }
        )
        if threads:
            env["RAYTILE_THREADS"] = str(threads)
        if database:
            env["RAYTILE_DATABASE_URL"] = database
        self.proc = subprocess.Popen(
            [binary, "serve"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
        )
        for _ in range(200):
            try:
                if request(self.url + "/readyz", timeout=1)[0] == 200:
                    return
            except OSError:
                pass
            time.sleep(0.05)
        self.stop()
        raise SystemExit("the server did not start: " + self.proc.stderr.read().decode())

    def metric(self, name):
        _, text = request(self.url + "/metrics")
        for line in text.decode().splitlines():
            if line.startswith(name + " "):
                return float(line.split()[1])
        return None

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(timeout=40)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        shutil.rmtree(self.data, ignore_errors=True)


def push(server, assignment_id, scenes):
    doc = {
        "version": 1,
        "title": "Benchmark " + assignment_id,
        "scenes": [
            {"name": f"s{k}", "scene": s, "points": 2, "grade": "image", "visibility": "visible"}
            for k, s in enumerate(scenes)
        ],
    }
    status, body = request(
        f"{server.url}/v1/assignments/{assignment_id}",
        "PUT",
        json.dumps(doc).encode(),
        auth({"Content-Type": "application/json"}),
    )
    if status not in (200, 201):
        raise SystemExit(f"push {assignment_id}: {status} {body[:500]!r}")


def render(server, s):
    status, png = request(
        server.url + "/v1/render",
        "POST",
        json.dumps(s).encode(),
        auth({"Content-Type": "application/json"}),
    )
    if status != 200:
        raise SystemExit(f"render: {status} {png[:500]!r}")
    return png


def submit(server, assignment_id, student, files):
    body, ctype = multipart(student, files)
    started = time.perf_counter()
    status, answer = request(
        f"{server.url}/v1/assignments/{assignment_id}/submissions",
        "POST",
        body,
        auth({"Content-Type": ctype}),
    )
    elapsed = time.perf_counter() - started
    if status not in (200, 201):
        raise SystemExit(f"submit: {status} {answer[:500]!r}")
    result = json.loads(answer)
    if result.get("score") != result.get("max_score"):
        raise SystemExit(f"a correct submission did not earn full marks: {answer[:800]!r}")
    return elapsed


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--binary", default=os.path.join(ROOT, "target", "release", "raytile"))
    p.add_argument("--database", help="a PostgreSQL URL (default: SQLite in a fresh folder)")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--clients", type=int, default=16)
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--threads", type=int, help="the server's trace threads (default: cores)")
    args = p.parse_args()

    server = Server(args.binary, args.database, args.threads)
    try:
        first, cached = [], []
        for r in range(args.rounds):
            aid = f"bench-{secrets.token_hex(4)}-{r}"
            scenes = [scene(r, k) for k in range(5)]
            push(server, aid, scenes)
            files = {f"s{k}": render(server, s) for k, s in enumerate(scenes)}
            first.append(submit(server, aid, f"first-{r}", files))
            cached.append(submit(server, aid, f"second-{r}", files))
            print(f"round {r}: first {first[-1]:.3f} s, cached {cached[-1]:.3f} s", flush=True)
        f, c = statistics.median(first), statistics.median(cached)
        print(f"median first submission {f:.3f} s, cached {c:.3f} s: ratio {c / f:.3f}")

        done, stop_at = [], time.perf_counter() + args.seconds
        lock = threading.Lock()

        def client(i):
            n = 0
            while time.perf_counter() < stop_at:
                t = submit(server, aid, f"client-{i}-{n}", files)
                n += 1
                with lock:
                    done.append(t)

        started = time.perf_counter()
        threads = [threading.Thread(target=client, args=(i,)) for i in range(args.clients)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        elapsed = time.perf_counter() - started
        print(
            f"{args.clients} clients: {len(done)} submissions in {elapsed:.1f} s = "
            f"{len(done) / elapsed:.2f} per second, median latency "
            f"{statistics.median(done):.3f} s"
        )
        print(
            "reference cache: hits",
            server.metric("raytile_reference_cache_hits_total"),
            "misses",
            server.metric("raytile_reference_cache_misses_total"),
            "entries",
            server.metric("raytile_reference_cache_entries"),
        )
    finally:
        server.stop()


if __name__ == "__main__":
    sys.exit(main())
