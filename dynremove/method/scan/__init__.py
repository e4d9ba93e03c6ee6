"""The scan of Sec. 3.2: compiled kernel, readable reference and the driver."""
