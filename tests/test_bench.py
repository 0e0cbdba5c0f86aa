"""`almsdm bench`: one run writes the issue's JSON keys, with numbers that hang together."""

import json

from almsdm_warp.cli.main import main


def test_bench_json_keys(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "--quick", "--batch", "4,8", "--rings", "2", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["device"] == "cpu"
    assert [(r["rings"], r["integrator"]) for r in data["single"]] == [(k, i) for i in ("explicit", "implicit") for k in (1, 2, 3, 4)]
    for row in data["single"]:
        assert set(row) == {"rings", "integrator", "steps_per_s", "step_us_median"}
        assert abs(row["steps_per_s"] * row["step_us_median"] * 1e-6 - 1.0) < 1e-9  # the same median
    assert [(r["rings"], r["batch"]) for r in data["batch"]] == [(2, 4), (2, 8)]
    assert all(set(r) == {"rings", "batch", "region_steps_per_s"} and r["region_steps_per_s"] > 0 for r in data["batch"])
    assert [r["integrator"] for r in data["global"]] == ["explicit", "implicit"]
    assert all(set(r) == {"integrator", "steps_per_s"} and r["steps_per_s"] > 0 for r in data["global"])
    one = data["single"][1]["steps_per_s"]  # 2 rings, explicit: the batch's rings
    best = max(r["region_steps_per_s"] for r in data["batch"])
    assert abs(data["ratios"]["batch_best_over_single_explicit"] - best / one) < 1e-9 * best / one
    assert "newton" in data and "region-steps/s" in capsys.readouterr().out
