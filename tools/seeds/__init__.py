"""The seed papers' headline experiments as library functions: the paper's numbers beside ours."""
