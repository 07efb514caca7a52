//! GenICam cameras (GigE Vision, USB3 Vision) through aravis (feature `cam-aravis`).

mod acquisition;

pub use acquisition::*;
