"""
Abusive inputs and settings, each through the `mvbb` command in a bounded process of its own.

The cases are ``benchmarks/abuse.py``'s (which prints them as a table, for this tree or
another): each runs under an address-space limit (1.5 GB) and a time limit, and must end with
its expected exit code, without a traceback, using less than a gigabyte of resident memory
(more only where a setting lifts the node's caps on purpose: the case says how much).
The heavy ones are ``slow``; the longest (minutes) is only in the benchmark, its smaller twin here.
"""

from __future__ import annotations

import pytest
from support.data import load_benchmark, REPO_ROOT

abuse = load_benchmark('abuse')

#: Resident memory each case must stay under, MiB (the issue's bound).
#: What each case's output must say (the line a user reads).
SAYS = {
    'blobs300': 'max_objects: kept the 16 largest of',
    'blobs300_all_objects': 'object(s)',
    'paper_gain1_sphere50k': 'boxes',
    'paper_gain1_min1_rescore32_sphere10k': 'boxes',
    'voxel0_200k': 'boxes',
    'corrupt_bag': f'skipped {len(abuse.CORRUPT_POSITIONS)} messages of /camera/points that do '
    'not deserialize',
    'lying_ply_header': 'the PLY header promises at least 12000000000 bytes of data',
}


@pytest.mark.parametrize(
    'case',
    [
        pytest.param(case, marks=[pytest.mark.slow] if case.heavy else [])
        for case in abuse.CASES
        if case.tested
    ],
    ids=lambda case: case.name,
)
def test_an_abusive_case_ends_cleanly_within_its_limits(tmp_path, case):
    outcome = abuse.run_case(case, tmp_path, tree=REPO_ROOT)
    assert not outcome.timed_out, f'{case.name}: killed after {outcome.seconds:.0f} s'
    assert not outcome.traceback, outcome.output[-3000:]
    assert outcome.code in case.codes, outcome.output[-3000:]
    assert outcome.peak_mb < case.peak_mb, f'{case.name}: {outcome.peak_mb:.0f} MiB'
    assert SAYS[case.name] in outcome.output, outcome.output[-3000:]
