"""Session files: recording what the live loop did, tick by tick, and reading it back.

One module per job (the public names are also at the top level: ``arsurf.SessionWriter``,
``arsurf.load_session``, ``arsurf.recover_session``):

========================  =====================================================================
module                    job
========================  =====================================================================
``schema``                the file format (root attributes, ``/metadata``, ``/ticks`` tables),
                          the per-tick fields of a metadata, the SHA-256 checksums
``writer``                :class:`~arsurf.sessions.writer.SessionWriter` (ticks streamed to a
                          journal, the sealed ``.h5`` written at close), ``write_h5``,
                          ``record_loop_tick``
``reader``                :func:`~arsurf.sessions.reader.load_session`, ``read_h5`` (seal,
                          schema, checksums; unsealed files in an isolated child process)
``recover``               :func:`~arsurf.sessions.recover.recover_session`: a killed
                          recording's journal written into its session file
``journal``               the crash-safe append-only journal a recording streams into
``sealed``                the seal of the HDF5 user block and the isolated reader process
``instrument_session``    a live session driven by an AFM's measured signals, recorded
``display``               notebook display of sessions and replays
========================  =====================================================================

Replaying a session (re-running the model over it) is :mod:`arsurf.replay`.
"""
