"""The speed benchmarks (``grasp-env bench``): rates beside references measured in the same run."""
