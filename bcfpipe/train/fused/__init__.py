"""A fused CPU training step (numba): features, MLP, loss and gradients in one pass over the samples
(issue 30). The torch path (bcfpipe.model.neural) stays the reference it is tested against, and the
path for CUDA."""
