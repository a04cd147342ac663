"""Fixtures shared by several test modules."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from usd_gs.cli import main

# Fuzz tests (tests/test_fuzz_*.py): a fixed, small number of examples so the suite stays within its
# time budget; 'ci' is loaded by default, pass --hypothesis-profile dev for a longer local run.
settings.register_profile("ci", max_examples=12, deadline=None, derandomize=True, print_blob=True,
                          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
settings.register_profile("dev", max_examples=200, deadline=None,
                          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
settings.load_profile("ci")


def _digests(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="session")
def quick_demo(tmp_path_factory):
    """Path of the --quick demo stage (``usd_gs.demo.stage.QUICK``), made once per test session
    through the CLI entry (``usdgs demo make --quick``, data found by the default search) into a
    folder ``stages/`` that does not exist yet.

    Shared by test_demo_stage, test_process and test_render_cli: tests must only read it (write
    outputs to their own ``tmp_path``). Teardown checks that no file of the demo folder changed."""
    out = tmp_path_factory.mktemp("demo") / "stages" / "demo.usda"
    assert main(["demo", "make", "-o", str(out), "--quick", "-q"]) == 0
    before = _digests(out.parent)
    yield out
    assert _digests(out.parent) == before, "a test modified the shared quick demo folder"
