"""A long mixed load on `sinrun serve`: whether the service holds it.

`sinrun serve` (every shipped model) runs in a child process; a few client
threads send it, for --minutes, a mix drawn from one seeded generator:
samples in every format, at scale 1 and 2 (seeds from a small range, so
that the cache is hit too), game assets, world tiles at several levels of
detail, layouts fetched and uploaded back, height maps uploaded, clients
that hang up before their answer, and hostile requests of the probes'
classes (values out of range, unknown models, a body of 400 MB declared or
5 MB chunked, a layout that is not one, too many kept parts). It reports
requests served, answers by status, latency percentiles per kind, the
server's resident memory every minute, tracebacks in its log, and whether
every sampling slot is free at the end. The cache of finished files
(256 MB by default) fills as the run goes: its size is printed beside the
memory, to tell it from a leak.

    python benchmarks/soak.py                    # 20 minutes, 3 clients
    python benchmarks/soak.py --minutes 2        # a short look

Targets: no 5xx, no traceback, memory within 10% of the first minute's
after it, every slot free at the end. Linux only (/proc). Run it on a quiet
machine: its latencies are the machine's.
"""

import argparse
import http.client
import io
import json
import random
import socket
import subprocess
import sys
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

SINRUN = "from sinshape.cli.main import main; main()"
MODELS = ("terrain", "towerruins", "brickruin")
FORMATS = ("ply", "obj", "stl", "npz", "glb")


def free_port() -> int:
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        return free.getsockname()[1]


class Client:
    """One connection's requests: (status, body) of each, by kind."""

    def __init__(self, port: int):
        self.port = port

    def send(self, method: str, path: str, body: bytes | None = None, headers=None, chunks=None) -> tuple:
        connection = http.client.HTTPConnection("127.0.0.1", self.port, timeout=300)
        try:
            if chunks is None:
                connection.request(method, path, body=body, headers=headers or {})
            else:  # sent by hand: chunked, or a length declared and never sent
                connection.putrequest(method, path)
                for name, value in (headers or {}).items():
                    connection.putheader(name, value)
                connection.endheaders()
                for chunk in chunks:
                    connection.send(b"%x\r\n%s\r\n" % (len(chunk), chunk))
            answer = connection.getresponse()
            return answer.status, answer.read()
        finally:
            connection.close()

    def hang_up(self, path: str) -> tuple:
        """Ask, then leave before the answer comes: the server frees the slot."""
        with socket.create_connection(("127.0.0.1", self.port)) as connection:
            connection.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
            time.sleep(0.05)
        return 0, b""


def height_map(rng) -> bytes:
    out = io.BytesIO()
    np.save(out, rng.uniform(-4, 4, (4, 4)).astype(np.float32))
    return out.getvalue()


def one_request(client: Client, rng: random.Random) -> tuple:
    """(kind, status) of one request drawn from the mix."""
    model = rng.choice(MODELS)
    seed = rng.randrange(40)
    kind = rng.choices(["sample", "asset", "tile", "layout", "map", "hang_up", "hostile", "health"],
                       weights=[30, 8, 20, 8, 6, 6, 18, 4])[0]
    if kind == "sample":
        fmt = rng.choice(FORMATS)
        status = client.send("GET", f"/api/models/{model}/sample?seed={seed}&format={fmt}&scale={rng.choice([1, 2])}")[0]
    elif kind == "asset":
        status = client.send("GET", f"/api/models/{model}/sample?seed={seed}&format=glb&lods=2000,500")[0]
    elif kind == "tile":
        i, j, lod = rng.randrange(-3, 4), rng.randrange(-3, 4), rng.randrange(3)
        status = client.send("GET", f"/api/models/terrain/tile?i={i}&j={j}&lod={lod}&format=glb")[0]
    elif kind == "layout":
        status, body = client.send("GET", f"/api/models/{model}/layout?seed={seed}&format=vox")
        if status == 200:
            status = client.send("POST", f"/api/models/{model}/sample?seed={seed + 1}&format=npz", body,
                                 {"Content-Type": "application/octet-stream"})[0]
    elif kind == "map":
        status = client.send("POST", f"/api/models/terrain/tile?i={rng.randrange(4)}&j=0&format=ply",
                             height_map(np.random.default_rng(seed)), {"Content-Type": "application/octet-stream"})[0]
    elif kind == "hang_up":
        status = client.hang_up(f"/api/models/{model}/sample?seed={1000 + rng.randrange(10**6)}&scale=2")[0]
    elif kind == "hostile":
        kind, status = hostile(client, rng, model)
    else:
        status = client.send("GET", "/health")[0]
    return kind, status


HOSTILE = ("seed -1", "scale 1e9", "unknown model", "400 MB declared", "5 MB chunked", "not a layout",
           "17 kept parts", "NaN map")


def hostile(client: Client, rng: random.Random, model: str) -> tuple:
    """(kind, status) of one hostile request: each must be a 4xx."""
    case = rng.choice(HOSTILE)
    octets = {"Content-Type": "application/octet-stream"}
    if case == "seed -1":
        status = client.send("GET", f"/api/models/{model}/sample?seed=-1")[0]
    elif case == "scale 1e9":
        status = client.send("GET", f"/api/models/{model}/sample?scale=1e9")[0]
    elif case == "unknown model":
        status = client.send("GET", "/api/models/..%2Fetc%2Fpasswd/sample")[0]
    elif case == "400 MB declared":
        status = client.send("POST", f"/api/models/{model}/sample", headers={**octets, "Content-Length": str(400 << 20)},
                             chunks=[])[0]
    elif case == "5 MB chunked":
        status = client.send("POST", "/api/models/terrain/tile?i=0&j=0", headers={**octets, "Transfer-Encoding": "chunked"},
                             chunks=[b"x" * (64 << 10)] * 80)[0]
    elif case == "not a layout":
        status = client.send("POST", f"/api/models/{model}/sample", b"PK not a zip", octets)[0]
    elif case == "17 kept parts":
        parts = "&".join(f"keep={s}:0%,0%,0%:50%,50%,50%" for s in range(17))
        status = client.send("GET", f"/api/models/{model}/sample?seed=1&{parts}")[0]
    else:
        out = io.BytesIO()
        np.save(out, np.array([[0.0, np.nan]], np.float32))
        status = client.send("POST", "/api/models/terrain/tile?i=0&j=0", out.getvalue(), octets)[0]
    return f"hostile: {case}", status


def resident_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def percentile(values, q) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=20.0)
    parser.add_argument("--clients", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--log", type=Path, default=Path("soak-server.log"), help="Where the server's log goes.")
    options = parser.parse_args()

    port = free_port()
    log = options.log.open("w")
    server = subprocess.Popen([sys.executable, "-c", SINRUN, "serve", "--port", str(port)], stderr=log, stdout=log)
    client = Client(port)
    deadline = time.monotonic() + 120
    while True:
        try:
            if client.send("GET", "/health")[0] == 200:
                break
        except OSError:
            pass
        if time.monotonic() > deadline or server.poll() is not None:
            raise SystemExit("the server did not start: see " + str(options.log))
        time.sleep(0.2)

    latencies, statuses = defaultdict(list), defaultdict(Counter)
    lock, stop = threading.Lock(), time.monotonic() + options.minutes * 60
    failures = []

    def work(number: int) -> None:
        rng = random.Random(options.seed * 1000 + number)
        while time.monotonic() < stop:
            started = time.monotonic()
            try:
                kind, status = one_request(client, rng)
            except OSError as error:  # the server closed a connection it should have answered
                kind, status = "connection error", 0
                failures.append(repr(error))
            with lock:
                latencies[kind].append(time.monotonic() - started)
                statuses[kind][status] += 1

    threads = [threading.Thread(target=work, args=(n,), daemon=True) for n in range(options.clients)]
    began = time.monotonic()
    for thread in threads:
        thread.start()
    memory, cached = [], []
    while any(thread.is_alive() for thread in threads):
        minute = len(memory) + 1
        while time.monotonic() < began + 60 * minute and any(t.is_alive() for t in threads):
            time.sleep(1)
        memory.append(resident_mb(server.pid))
        cached.append(json.loads(client.send("GET", "/health")[1])["cached_bytes"] / 2**20)
        with lock:
            served = sum(sum(c.values()) for c in statuses.values())
        print(f"minute {minute}: {served} requests, server {memory[-1]:.0f} MB, its cache {cached[-1]:.0f} MB",
              file=sys.stderr, flush=True)
    time.sleep(2)  # the last hung-up clients' jobs end
    health = json.loads(client.send("GET", "/health")[1])
    server.terminate()
    server.wait(timeout=60)
    log.close()
    text = options.log.read_text()

    every = Counter()
    for counts in statuses.values():
        every.update(counts)
    print(f"{options.minutes:g} minutes, {options.clients} clients: {sum(every.values())} requests "
          f"({sum(every.values()) / (time.monotonic() - began):.1f} a second)")
    print("answers by status:", ", ".join(f"{s or 'hung up'}: {n}" for s, n in sorted(every.items())))
    print("\n| kind | requests | statuses | p50 s | p90 s | p99 s |\n|---|---|---|---|---|---|")
    for kind in sorted(latencies):
        times = latencies[kind]
        shown = ", ".join(f"{s or 'hung up'}: {n}" for s, n in sorted(statuses[kind].items()))
        print(f"| {kind} | {len(times)} | {shown} | {percentile(times, 50):.3f} | {percentile(times, 90):.3f} "
              f"| {percentile(times, 99):.3f} |")
    later = memory[1:] or memory
    print("\nserver memory each minute (MB):", " ".join(f"{m:.0f}" for m in memory))
    print("of it, finished files in its cache (MB):", " ".join(f"{m:.0f}" for m in cached))
    print(f"after the first minute: {min(later):.0f} to {max(later):.0f} MB, "
          f"{100 * (max(later) / memory[0] - 1):+.1f}% at most against the first minute's {memory[0]:.0f} MB")
    print(f"5xx: {sum(n for s, n in every.items() if s >= 500)}; tracebacks in the log: {text.count('Traceback')}; "
          f"connection errors: {len(failures)}")
    print(f"at the end: {health['sampling']} sampling, {health['in_flight']} in flight (every slot free: "
          f"{health['sampling'] == 0 and health['in_flight'] == 0})")


if __name__ == "__main__":
    main()
