//! Fetch of the real captures (in progress).
