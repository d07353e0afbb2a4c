"""A ``loopid reproduce`` run against a reference run, under the equivalence rule an engine
change that may move bits is held to (``benchmarks/equivalence_rule.py``: the rule, its readings
and the per-cell report).

    .venv/bin/python benchmarks/equivalence.py REFERENCE_RUN_DIR NEW_RUN_DIR

Printed: every (scenario, method) cell's clause, final medians, relative change and outcome, the
largest change of a settled cell's median, the findings' verdicts, the MDP table's columns and
the failed clauses (Markdown, for the CHANGELOG). Exit status 0 when the runs are equivalent, 1
when a clause fails. Without arguments (``make bench`` runs every script so) it prints its usage
and exits 0: there is nothing to compare.
"""

import argparse
import sys
from pathlib import Path

# The rule is this script's sibling (a script's own folder is on sys.path), not in the package;
# the tests import it as ``benchmarks.equivalence_rule``.
import equivalence_rule


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("reference", type=Path, nargs="?", help="The reference reproduce run.")
    parser.add_argument("new", type=Path, nargs="?", help="The run to check against it.")
    args = parser.parse_args(argv)
    if args.reference is None or args.new is None:
        if args.reference is not None:
            parser.error("give the new run directory too")
        parser.print_usage()
        print("Nothing to compare: give a reference run directory and a new one.")
        return 0
    result = equivalence_rule.evaluate(args.reference, args.new)
    print(f"# {args.new} against {args.reference}\n")
    print("\n".join(equivalence_rule.report(result)))
    return 1 if result.failures else 0


if __name__ == "__main__":
    sys.exit(main())
