"""Files and formats: atomic writes, panoramas and depth maps, MP4 video and its 360° metadata."""
