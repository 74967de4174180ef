# The two commands of the README: `make demo` and `make test`. Both create and reuse .venv.
PYTHON ?= python3.11
VENV := .venv
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml setup.py
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) on PATH (or make PYTHON=python3)"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --upgrade pip
	$(VENV)/bin/python -m pip install --quiet -e '.[test,bench]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/ubitrack demo

test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/python -m pytest

bench: $(STAMP)
	for name in plan_bench accuracy_bench calibration_bench dataflow_bench hop_cost_bench call_cost_bench \
		worker_start static_estimate_bench calibration_flows_bench calibrated_tracking_bench fuzz_bench \
		agent_restart_bench churn_bench recovery_bench camera_bench fusion_latency_bench \
		clock_bench hosts_bench building_bench agent_replan_bench agent_live_bench materialise_bench \
		containers_bench container_hop_bench container_add_bench throughput_bench decode_run_bench reroute_bench \
		chaos_runs_bench switch_bench pnp_ambiguity_bench recording_bench ros2_bench view_frames_bench natnet_bench \
		answer_latency_bench demo_phases_bench fusion_consistency_bench consider_cost_bench \
		camera_consistency_bench stall_bench attachment_bench provider_leave_bench flowing_bench \
		fusion_gap_bench; do \
		$(VENV)/bin/python -m bench.$$name || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache .hypothesis
