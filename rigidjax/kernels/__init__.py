"""Hand-written CPU kernels for hot paths, called through XLA's FFI (`jax.ffi`), built on the
user's machine on first use (`_build`). Each has a pure-JAX path with the same numbers, which
runs where the kernel cannot (another backend, no C++ compiler) and gives its derivatives."""
