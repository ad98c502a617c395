"""The shipped weights in `assets/`: depth and renderer networks (`networks`), LPIPS (`lpips`)."""
