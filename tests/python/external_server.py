#!/usr/bin/env python3
"""A test server of the external-model contract with faults on demand: it serves builtin's
start (the contact's previous impulse) and, as asked, answers some steps late or fails at a step.

  --late-every K --late-by S   answer every K-th step (step % K == 0) S seconds late
  --fail-at-step N             raise at step N (a crashing server)
"""
import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "python"))
from deep_contact import main_guard, serve  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--late-every", type=int, default=0)
    parser.add_argument("--late-by", type=float, default=0.0)
    parser.add_argument("--fail-at-step", type=int, default=-1)
    args = parser.parse_args()

    def predict(problem):
        _run, _simulation, step = problem.key
        if step == args.fail_at_step:
            raise RuntimeError(f"the test server fails at step {step}, as asked")
        if args.late_every and step % args.late_every == 0:
            time.sleep(args.late_by)
        return problem.contacts["previous"]

    serve(predict)


if __name__ == "__main__":
    main_guard(main)
