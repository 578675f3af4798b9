"""`softforce report`: a sense or diagnose output folder as a terminal summary, an HTML page,
PNG figures, re-exported tables and a Foxglove replay."""
