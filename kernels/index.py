"""An index the compiler may take as non-negative."""

import warp as wp


@wp.func_native("__builtin_assume(i >= 0);\nreturn i;")
def nonneg(i: int) -> int: ...
