"""The fuzz harness against misbehaviour of known kind (misbehave.act): a refusal, a
traceback, sys.exit, SIGSEGV, a hang, an allocation beyond the address-space limit and one
that succeeds above the RSS limit are each classified as what they are, and the inputs after
a child that died are still run."""

import numpy as np
from harness import names_file_and_field, run_cli, run_reader


def test_each_misbehaviour_is_classified_and_the_rest_still_runs():
    kinds = ["ok", "clean", "traceback", "exit", "crash", "ok", "hang", "memory", "rss", "ok"]
    # The children's RSS limit lowered to 300 MiB: "rss" allocates 400 MiB, and succeeds.
    outcomes = run_reader("misbehave:act", kinds, timeout_s=5, env={"SOFTVR_FUZZ_RSS": str(300 << 20)})
    expected = ["ok", "clean", "traceback", "exit", "crash", "ok", "hang", "memory", "memory", "ok"]
    assert [o.kind for o in outcomes] == expected, [(o.kind, o.detail[-200:]) for o in outcomes]
    assert "SIGSEGV" in outcomes[4].detail
    assert names_file_and_field(outcomes[1], "/data/scene.toml")
    assert not names_file_and_field(outcomes[1], "/data/other.toml")


def test_a_command_is_classified_by_exit_status_and_stderr(tmp_path):
    missing = tmp_path / "none.toml"
    refused = run_cli(["check", missing])
    assert refused.kind == "clean" and refused.extra["code"] == 2
    assert names_file_and_field(refused, missing) and not names_file_and_field(refused, tmp_path / "other.toml")
    assert run_cli(["--help"]).kind == "ok"


def test_a_child_is_measured_by_its_own_memory_not_its_parents():
    # A parent holding 400 MiB (as pytest does, ~1.5 GiB, late in the full suite) and children
    # limited to 300 MiB that use ~100 MiB: each child's peak is its own (Linux VmHWM), so the
    # inputs run in one child and none counts as memory. ru_maxrss, which exec keeps from the
    # forking parent, made every input "memory" and forked a child per input.
    held = np.ones(400 << 20, np.uint8)
    limit = {"SOFTVR_FUZZ_RSS": str(300 << 20)}
    outcomes = run_reader("misbehave:act", ["ok"] * 5, timeout_s=5, env=limit)
    assert [o.kind for o in outcomes] == ["ok"] * 5, [(o.kind, o.detail[-200:]) for o in outcomes]
    assert max(o.rss_bytes for o in outcomes) < 300 << 20
    assert run_cli(["--help"], env=limit).kind == "ok"
    assert held.sum() == 400 << 20
