"""Plain ``nn.Module`` components: the DeepLab-v2 segmenter, PatchGAN discriminators, weights."""
