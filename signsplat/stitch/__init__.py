"""Sign stitching: English text -> gloss plan (``text``), gloss clips -> continuous SMPL-X
motion (``motion``), import of user gloss clips and hand-mean conventions (``library``)."""
