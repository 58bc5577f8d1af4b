"""glibc keeps freed tensor memory once training has asked it to (helpers.core.allocator)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from helpers.core.allocator import _glibc

# One fresh process per setting (the setting is process-wide): allocate and free a 50 MB float
# tensor (one step's activation at batch 16, 64 px), touching every page, 10 times to warm up (glibc's
# heap grows for the first few; 7 measured), then count the minor page faults of 10 more.
_PROBE = """
import json, resource, torch
from helpers.core.allocator import keep_freed_memory
rec = keep_freed_memory()
torch.ones(1)
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for k in range(20):
    if k == 10:
        f0 = faults()
    t = torch.ones(48, 64, 64, 64)
    del t
print(json.dumps({"record": rec, "faults": faults() - f0}))
"""


def _probe(opt_out: bool) -> dict:
    env = dict(os.environ, HELPERS_KEEP_FREED_MEMORY="0" if opt_out else "1")
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, check=True,
                         timeout=120)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(_glibc() is None, reason="the C library is not glibc: keep_freed_memory changes nothing")
def test_freed_memory_is_reused_instead_of_faulted_in_again():
    default, kept = _probe(opt_out=True), _probe(opt_out=False)
    assert default["record"] == {"allocator": None, "keep_freed_memory": False,
                                 "reason": "HELPERS_KEEP_FREED_MEMORY=0"}
    assert kept["record"]["keep_freed_memory"] is True and kept["record"]["allocator"].startswith("glibc ")
    # 50 MB = 12,288 pages of 4 KiB: glibc's default maps (and the kernel zeroes) them again every time;
    # kept, the warm heap serves all 10 without touching a new page (fewer faults than one allocation's pages)
    assert default["faults"] > 10 * 10_000, default
    assert kept["faults"] < 12_288 // 2, kept


def test_the_record_is_returned_once_per_process():
    from helpers.core.allocator import keep_freed_memory

    assert keep_freed_memory() is keep_freed_memory()
