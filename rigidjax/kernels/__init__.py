"""Hand-written kernels for hot paths: C++ for the CPU, called through XLA's FFI (`jax.ffi`)
and built on the user's machine on first use (`_build`), and Pallas for GPUs. Each has a
pure-JAX path with the same numbers, which runs where no kernel can (another backend, no C++
compiler) and gives the derivatives of the Pallas kernel."""
