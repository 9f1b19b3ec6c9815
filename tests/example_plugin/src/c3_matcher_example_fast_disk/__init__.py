"""Example third-party strategy ``example_fast_disk``: the shared DISK + LightGlue engines at a
small keypoint budget and image size (options ``max_keypoints``, ``max_long_side``)."""
