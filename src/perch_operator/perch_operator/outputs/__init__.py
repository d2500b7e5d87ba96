"""A mission's outputs: the MCAP recording (writer and reader), mission data, report, pictures and the rerun recording."""
