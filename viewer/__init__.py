"""The Open3D research viewer (imports fracture/ and fields/, never the reverse)."""
