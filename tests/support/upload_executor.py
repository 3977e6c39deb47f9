"""An upload executor for the tests that must see ``POST /stereo``'s work in their own process:
``create_app(..., upload_executor=thread_uploads)``. The route takes its one path
(``UploadPool.run(process_upload, ...)``); only the executor differs from the deployed
app's worker processes."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor


def thread_uploads(max_workers: int) -> ThreadPoolExecutor:
    """``max_workers`` threads of this process (an ``ExecutorFactory``)."""
    return ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix="aar-upload-test")
