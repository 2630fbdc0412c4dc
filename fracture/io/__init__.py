"""Files in and out: meshes checked at the door, OBJ, PLY and USD output, exports of finished runs,
and atomic writing."""
