//! Finding GenICam cameras: aravis's device list, and a GigE Vision discovery probe of one
//! address that answers within a timeout (so a lost camera is not waited on for seconds).

use std::ffi::{CStr, c_char};
use std::net::{Ipv4Addr, SocketAddrV4, UdpSocket};
use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

/// The GigE Vision control protocol's UDP port.
pub const GVCP_PORT: u16 = 3956;

/// Serialises use of aravis's global device list (its strings live until the next update).
static DEVICE_LIST: Mutex<()> = Mutex::new(());

/// One GenICam device as aravis's discovery sees it.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct ListedDevice {
    /// The id aravis opens it by (`vendor-model-serial` for GigE).
    pub id: String,
    /// Network address (GigE) or bus address (USB).
    pub address: String,
    /// Serial number as the device reports it (`port` may name the camera by it).
    pub serial: String,
    /// Manufacturer name, for the operator.
    pub vendor: String,
    /// Model name, for the operator.
    pub model: String,
    /// `GigEVision`, `USB3Vision`, `Fake`, …
    pub protocol: String,
    /// MAC address (GigE) or bus id (USB).
    pub physical_id: String,
}

/// Every GenICam device aravis can see now. GigE discovery waits about a second for answers.
pub fn list_devices() -> Vec<ListedDevice> {
    let _guard = DEVICE_LIST.lock().unwrap_or_else(PoisonError::into_inner);
    /// Copies a C string aravis owns (empty for NULL).
    ///
    /// # Safety
    /// `p` is NULL or a NUL-terminated string valid for the duration of the call.
    unsafe fn text(p: *const c_char) -> String {
        if p.is_null() {
            String::new()
        } else {
            // SAFETY: non-NULL and NUL-terminated per the caller's contract.
            unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
        }
    }
    // SAFETY: the list is global state in aravis; the guard makes this the only code in the
    // process that updates or reads it, and every string is copied before the guard drops.
    unsafe {
        aravis_sys::arv_update_device_list();
        let n = aravis_sys::arv_get_n_devices();
        (0..n)
            .map(|i| ListedDevice {
                id: text(aravis_sys::arv_get_device_id(i)),
                address: text(aravis_sys::arv_get_device_address(i)),
                serial: text(aravis_sys::arv_get_device_serial_nbr(i)),
                vendor: text(aravis_sys::arv_get_device_vendor(i)),
                model: text(aravis_sys::arv_get_device_model(i)),
                protocol: text(aravis_sys::arv_get_device_protocol(i)),
                physical_id: text(aravis_sys::arv_get_device_physical_id(i)),
            })
            .collect()
    }
}

/// Whether a GigE Vision device answers a unicast GVCP discovery at `address` within
/// `timeout`. Cheap, so a lost camera is probed before aravis spends seconds on retries.
pub fn gvcp_probe(address: Ipv4Addr, timeout: Duration) -> bool {
    const REQ_ID: u16 = 0x5348;
    let Ok(socket) = UdpSocket::bind((Ipv4Addr::UNSPECIFIED, 0)) else {
        return false;
    };
    // GVCP command header: key 0x42, flags (ack required), DISCOVERY_CMD, no payload, req id.
    let [hi, lo] = REQ_ID.to_be_bytes();
    let discovery = [0x42, 0x01, 0x00, 0x02, 0x00, 0x00, hi, lo];
    if socket
        .send_to(&discovery, SocketAddrV4::new(address, GVCP_PORT))
        .is_err()
    {
        return false;
    }
    let deadline = Instant::now() + timeout;
    let mut reply = [0u8; 600];
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() || socket.set_read_timeout(Some(left)).is_err() {
            return false;
        }
        match socket.recv_from(&mut reply) {
            // DISCOVERY_ACK (0x0003) carrying our request id.
            Ok((n, _)) if n >= 8 && reply[2..4] == [0x00, 0x03] && reply[6..8] == [hi, lo] => {
                return true;
            }
            Ok(_) => {}
            Err(_) => return false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Nothing listens on this loopback address's GVCP port: the probe says so in time.
    #[test]
    fn probe_of_a_silent_address_is_false() {
        let t = Instant::now();
        assert!(!gvcp_probe(
            Ipv4Addr::new(127, 0, 0, 254),
            Duration::from_millis(100)
        ));
        assert!(t.elapsed() < Duration::from_secs(5));
    }
}
