//! Software-in-the-loop (SIL) tests: closed-loop runs of the flight software in the host
//! simulator, each tagged with the requirement id it verifies (`docs/requirements.md`). The
//! tests live in `tests/tests/`.
