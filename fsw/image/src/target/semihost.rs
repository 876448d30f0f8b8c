//! Host files through semihosting (QEMU `-semihosting-config enable=on,target=native`): the
//! command line and the call tape, read with SYS_OPEN, SYS_SEEK and SYS_READ.

use cortex_m_semihosting::{nr, syscall};
use rover_replay::tape::{ByteSource, PayloadSource};
use rover_replay::TapeError;

/// Largest path accepted (bytes, without the terminating NUL).
const MAX_PATH: usize = 200;

/// The semihosting command line (`-semihosting-config arg=...`), NUL-terminated in `buf`;
/// returns the text before the NUL.
pub fn command_line(buf: &mut [u8; 256]) -> &str {
    // SAFETY: SYS_GET_CMDLINE writes at most `buf.len()` bytes into `buf`.
    let failed = unsafe { syscall!(GET_CMDLINE, buf.as_mut_ptr(), buf.len()) } != 0;
    if failed {
        return "";
    }
    let end = buf.iter().position(|b| *b == 0).unwrap_or(buf.len());
    buf.get(..end)
        .and_then(|b| core::str::from_utf8(b).ok())
        .unwrap_or("")
}

/// A host file opened read-only in binary mode, with its read position.
pub struct HostFile {
    handle: usize,
    pos: u64,
}

impl HostFile {
    /// Open `path` for reading; `None` when the host refuses.
    pub fn open(path: &str) -> Option<Self> {
        let mut name = [0u8; MAX_PATH + 1];
        let bytes = path.as_bytes();
        name.get_mut(..bytes.len())?.copy_from_slice(bytes);
        // SAFETY: `name` is NUL-terminated after `bytes.len()` bytes and outlives the call.
        let handle = unsafe { syscall!(OPEN, name.as_ptr(), nr::open::R_BINARY, bytes.len()) };
        (handle != usize::MAX).then_some(Self { handle, pos: 0 })
    }

    /// Length of the file, bytes.
    pub fn len(&self) -> Option<u64> {
        // SAFETY: SYS_FLEN only reads the handle.
        let len = unsafe { syscall!(FLEN, self.handle) };
        (len != usize::MAX).then_some(len as u64)
    }

    fn seek(&mut self, pos: u64) -> Result<(), TapeError> {
        let at = usize::try_from(pos).map_err(|_| TapeError::Io)?;
        // SAFETY: SYS_SEEK only moves the host file's position.
        if unsafe { syscall!(SEEK, self.handle, at) } != 0 {
            return Err(TapeError::Io);
        }
        self.pos = pos;
        Ok(())
    }
}

impl ByteSource for HostFile {
    fn read_exact(&mut self, buf: &mut [u8]) -> Result<(), TapeError> {
        if buf.is_empty() {
            return Ok(());
        }
        // SAFETY: SYS_READ writes at most `buf.len()` bytes into `buf`.
        let not_read = unsafe { syscall!(READ, self.handle, buf.as_mut_ptr(), buf.len()) };
        if not_read != 0 {
            return Err(TapeError::Truncated);
        }
        self.pos = self.pos.saturating_add(buf.len() as u64);
        Ok(())
    }
    fn skip(&mut self, n: u64) -> Result<(), TapeError> {
        self.seek(self.pos.saturating_add(n))
    }
}

impl PayloadSource for HostFile {
    fn read_at(&mut self, offset: u64, buf: &mut [u8]) -> Result<(), TapeError> {
        self.seek(offset)?;
        self.read_exact(buf)
    }
}
