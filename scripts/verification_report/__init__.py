"""The verification report, ``docs/verification.md``, in three steps.

1. :mod:`.runs` runs the library and returns every number the report shows, with the
   constants of the code its prose needs, as plain data (written to
   ``verification-data.json``); :mod:`.figures` draws the figures from the same runs.
2. :mod:`.findings` decides, from that data alone, each statement that depends on it
   (booleans and categories, with the derived numbers they rest on).
3. :mod:`.render` fills the Markdown template ``verification.md.j2`` with the data and the
   findings: the prose lives there, and only there.
"""
