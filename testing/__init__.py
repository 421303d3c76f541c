"""Test and measurement support (``uss_slam.testing``, like ``torch.testing``): the independent
plain-PyTorch reference of one training iteration, and the code that the tests, the speed and
accuracy benchmarks (``benchmarks/``) and the research scripts (``studies/``) share. Nothing in
the product imports it."""
