"""Seal result records in place with the SHA-256 of their content, once checked by eye or written before records
were sealed: `python scripts/seal_records.py [RECORD.json ...]`; with no file, every record `vision-rl report` reads
under docs/results. A record sealed already and whole is left as it is; one whose content changed is refused."""

from __future__ import annotations

import sys
from pathlib import Path

from vision_rl.evaluation.report import records_read, seal_record_file

RESULTS_DIR = Path(__file__).resolve().parents[1] / "docs" / "results"


def main(argv: list[str]) -> int:
    paths = [Path(a) for a in argv] or records_read(RESULTS_DIR)
    try:
        sealed = [path for path in paths if seal_record_file(path)]
    except (OSError, ValueError) as exc:  # ReportError included: one line naming the file
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for path in sealed:
        print(f"sealed {path}")
    print(f"{len(sealed)} of {len(paths)} records sealed now; the others were sealed already")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
