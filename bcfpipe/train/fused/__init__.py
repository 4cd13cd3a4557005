"""A fused CPU training step: features, MLP, loss and gradients in one pass over the samples (issue
30). step.cpp is the vectorised C++ build (native.py compiles it into the cache on first use);
kernel.py is the same step in numba, for machines without a C++ compiler. The torch path
(bcfpipe.model.neural) stays the reference both are tested against, and the path for CUDA."""
