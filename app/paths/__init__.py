"""Camera paths: nerfstudio's ``camera_path.json``, splines through keyframes, rendered frames."""
