"""The 6DoF viewer: window, camera controls, render worker, display (`panogrf view`)."""
