"""The parts of ``ffviz.recorder.RerunRecorder``, by job: ``digest`` (a frame's pictures at the recorded size, made on
the rendering thread), ``view`` (the recorded size and how each kind of picture is brought to it), ``backlog`` (the
recorder's thread, bounded in bytes), ``sink`` (the file, written by a thread of ours), ``encoders`` (H.264, PNG,
JPEG), ``legends`` (colours and keys), ``fields`` (the table from result field to entity), ``about`` (the about tab).
"""
