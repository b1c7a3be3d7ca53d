"""The test suite's memory, test by test: a pytest plugin (Linux: it reads /proc).

    OMP_NUM_THREADS=1 PYTHONPATH=benchmarks /usr/bin/time -v pytest -q -p suite_memory [--suite-memory-log FILE]

After each test it notes the test process's resident memory (VmRSS) and
its peak so far (VmHWM), and what its child processes hold (chromium, the
servers, Ray's workers); at the end it prints the peaks, the tests that
raised the process's peak most, and the most the process and its children
held at once. With --suite-memory-log, every test's figures as a
tab-separated file. The figures are in docs/BENCHMARKS.md, "The test suite".
"""

import os
from pathlib import Path

RECORDS = []  # (test, MB resident, MB peak so far, MB in child processes, the largest children)
COLLECTED = [0.0]  # the peak once the tests are collected (their modules imported)


def pytest_addoption(parser):
    parser.addoption("--suite-memory-log", default=None, help="write every test's memory figures here (TSV)")


def status(pid) -> dict:
    """A process's /proc status fields, {} once it has gone."""
    try:
        return dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line)
    except OSError:
        return {}


def mb(fields: dict, name: str) -> float:
    return int(fields.get(name, "0 kB").split()[0]) / 1024


def children() -> list:
    """(MB resident, name) of every process below this one."""
    parents = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            fields = status(entry)
            if fields:
                parents[int(entry)] = (int(fields["PPid"]), mb(fields, "VmRSS"), fields["Name"].strip())
    mine, below = set(), {os.getpid()}
    while below:
        below = {pid for pid, (parent, _, _) in parents.items() if parent in below and pid not in mine}
        mine |= below
    return sorted(((parents[pid][1], parents[pid][2]) for pid in mine), reverse=True)


def pytest_collection_finish(session):
    COLLECTED[0] = mb(status(os.getpid()), "VmHWM")


def pytest_runtest_logfinish(nodeid, location):
    own, below = status(os.getpid()), children()
    RECORDS.append((nodeid, round(mb(own, "VmRSS")), round(mb(own, "VmHWM")), round(sum(r for r, _ in below)),
                    ", ".join(f"{name} {r:.0f}" for r, name in below[:3])))


def pytest_terminal_summary(terminalreporter, config):
    if not RECORDS:
        return
    path = config.getoption("suite_memory_log")
    if path:
        with open(path, "w") as f:
            f.write("test\tMB resident\tMB peak so far\tMB in child processes\tthe largest\n")
            f.writelines("\t".join(map(str, record)) + "\n" for record in RECORDS)
    raised, before = [], COLLECTED[0]
    for test, _, peak, _, _ in RECORDS:
        raised.append((peak - before, test))
        before = max(before, peak)
    most = max(RECORDS, key=lambda r: r[1] + r[3])
    below = max(RECORDS, key=lambda r: r[3])
    say = terminalreporter.write_line
    say(f"\nthe test process's peak resident memory: {RECORDS[-1][2]:.0f} MB "
        f"({COLLECTED[0]:.0f} MB once the tests were collected); at the end {RECORDS[-1][1]:.0f} MB")
    say(f"its child processes at once, at most: {below[3]:.0f} MB ({below[4]}), after {below[0]}")
    say(f"the process and its children at once, at most: {most[1] + most[3]:.0f} MB, after {most[0]}")
    say("the tests that raised the process's peak most:")
    for step, test in sorted(raised, reverse=True)[:5]:
        say(f"  +{step:.0f} MB  {test}")
