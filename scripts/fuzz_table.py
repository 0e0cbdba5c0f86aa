"""The table of fuzz cases and outcomes in docs/reliability.md, from a campaign's log.

    ALMSDM_FUZZ_SCALE=25 ALMSDM_FUZZ_LOG=/tmp/fuzz.jsonl python -m pytest -q tests/test_fuzz_*.py
    python scripts/fuzz_table.py /tmp/fuzz.jsonl

One row per fuzz test and case family: how many examples ran, how many ended in a result and
how many in a one-line error (exit code 2 on the command line), and the most frequent error.
A failure (a traceback, a hang, a half-written file) stops the test, so it is in pytest's
output, not here.
"""

from __future__ import annotations

import collections
import json
import re
import sys

TESTS = {
    "corrupted_file": "mesh file, corrupted",
    "random_arrays": "random arrays",
    "perturbed_icosahedron": "an icosahedron, perturbed",
    "random_mesh": "random mesh, written and read",
    "scene_edit": "scene file, values edited",
    "scene_bytes": "scene file, bytes corrupted",
    "scene_cli": "edited scene, `almsdm palpate`",
    "cli_extreme": "`almsdm` extreme flags",
}


def family(test: str, case: str) -> str:
    """The row a logged case goes in: the format for files, the kind of edit for scenes, the
    command and the kind of output path for the command line."""
    if test == "cli_extreme":
        command = case.split()[0]
        json_kind = case.split("json:")[-1]
        where = {"ok": "a writable path", "read-only folder": "a read-only folder (writable for root)"}.get(
            json_kind, "an unwritable path (missing folder, a folder, /proc, 300-character name)")
        return f"{command}, {where}"
    if test == "scene_cli":
        return "one to three edits"
    if test == "scene_edit":  # "edge_stiffness_N_per_m, no depth_mm" -> the first edit's kind
        first = case.split(",")[0].strip()
        return "key removed" if first.startswith("no ") else "key misspelt" if first.startswith("typo") else (
            "unknown section" if first == "unknown section" else "a value replaced")
    if test == "corrupted_file":
        return case.split(" ")[0] if case.split(" ")[1:2] not in (["POLYDATA"], ["grid"], ["v1"], ["v2.2"], ["v4.1"]) \
            else " ".join(case.split(" ")[:2])
    if test == "scene_bytes":
        return "one corruption"
    return case


def short(message: str) -> str:
    message = re.sub(r"^almsdm: error: ", "", message)
    message = re.sub(r"…/\S*", "…", message)
    message = re.sub(r"-?\d[\d.e+-]*", "N", message)
    return message[:70]


def main(path: str) -> int:
    rows = collections.OrderedDict()
    for line in open(path, encoding="utf-8"):
        d = json.loads(line)
        key = (d["test"], family(d["test"], d["case"]))
        row = rows.setdefault(key, {"ok": 0, "error": 0, "messages": collections.Counter()})
        row[d["outcome"]] += 1
        if d["outcome"] == "error":
            row["messages"][short(d["message"])] += 1
    print("| input | case | examples | result | one-line error | most frequent error |")
    print("|---|---|---|---|---|---|")
    total = collections.Counter()
    for (test, fam), row in sorted(rows.items(), key=lambda kv: (list(TESTS).index(kv[0][0]) if kv[0][0] in TESTS else 99, kv[0][1])):
        n = row["ok"] + row["error"]
        common = row["messages"].most_common(1)
        text = f"`{common[0][0]}`" if common else ""
        print(f"| {TESTS.get(test, test)} | {fam} | {n} | {row['ok']} | {row['error']} | {text} |")
        total["ok"] += row["ok"]
        total["error"] += row["error"]
    print(f"| **all** | | **{total['ok'] + total['error']}** | **{total['ok']}** | **{total['error']}** | |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
