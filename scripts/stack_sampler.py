"""Where a program's threads wait: sample every thread's Python stack while a script runs, and count the
innermost frames of the stacks that pass through the functions named.

    python scripts/stack_sampler.py --within plan _press_again -- scripts/bench_dataset.py --points 10000 --device cuda:0 --runs 1 --no-sweeps

Every --every-ms (default 5) a thread of its own reads sys._current_frames(); a stack with a frame of one
of the --within functions counts once for its innermost frame and the --depth frames under it. At the end
the --top stacks are printed with the time they were seen (samples x the period): a call that blocks in
native code (a CUDA copy, a synchronisation) shows as the Python frame that called it. A sampling
profiler, not a tracer: short calls may be missed, long waits are not.
"""

import argparse
import collections
import runpy
import sys
import threading
import time


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--within", nargs="+", required=True, help="function names: stacks through any of them are counted")
    ap.add_argument("--every-ms", type=float, default=5.0)
    ap.add_argument("--depth", type=int, default=6, help="frames under the innermost one shown")
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("script", help="the Python script to run")
    ap.add_argument("args", nargs=argparse.REMAINDER, help="its arguments")
    a = ap.parse_args(argv)
    within, counts, per, done = set(a.within), collections.Counter(), collections.Counter(), threading.Event()

    def where(frame):
        return f"{frame.f_code.co_filename.rsplit('/', 1)[-1]}:{frame.f_code.co_name}:{frame.f_lineno}"

    def sample():
        me = threading.get_ident()
        while not done.wait(a.every_ms * 1e-3):
            for tid, frame in sys._current_frames().items():
                if tid == me:
                    continue
                stack = []
                while frame is not None:
                    stack.append(frame)
                    frame = frame.f_back
                names = {f.f_code.co_name for f in stack}
                hit = names & within
                if hit:
                    counts[" <- ".join(where(f) for f in stack[: a.depth + 1])] += 1
                    for name in hit:
                        per[name] += 1

    thread = threading.Thread(target=sample, name="stack-sampler", daemon=True)
    thread.start()
    sys.argv = [a.script, *(x for x in a.args if x != "--")]
    t0 = time.perf_counter()
    try:
        runpy.run_path(a.script, run_name="__main__")
    except SystemExit:
        pass
    done.set()
    thread.join()
    ms = a.every_ms
    print(f"# {time.perf_counter() - t0:.1f} s; seen inside: " + ", ".join(f"{k} {v * ms / 1e3:.1f} s" for k, v in per.most_common()))
    for stack, n in counts.most_common(a.top):
        print(f"{n * ms / 1e3:8.2f} s  {stack}")


if __name__ == "__main__":
    main()
