"""The operator's live page: a local web page that follows a campaign (``campaign run --ui``) or just the
cameras and the rig (``stereo-bench live``).

state.py folds the document stream into what the page shows; preview.py makes the camera previews
and the calibration coverage off the capture path; transcript.py tails the rig's serial transcript;
server.py serves it all (Starlette on uvicorn, on a thread); page.py wires them and is the page's
operator (Continue, Capture now, Discard last view) and control (Pause, Resume, Stop). See docs/LIVE.md.
"""
