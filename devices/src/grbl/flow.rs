//! Character-counting flow control: GRBL's receive buffer holds 127 bytes, and a line may be
//! sent only if it fits beside the lines already sent but not yet answered by `ok`/`error`.
//! Each line gets a sequence number, so a reply can be matched to the line it answers (replies
//! come in order).

use std::collections::VecDeque;

/// Size of GRBL 1.1's serial receive buffer.
pub const RX_BUFFER: usize = 127;

/// Lines in flight to the controller, oldest first.
#[derive(Debug, Clone)]
pub struct Flow {
    capacity: usize,
    in_flight: VecDeque<(u64, usize)>,
    bytes: usize,
    next_seq: u64,
}

impl Default for Flow {
    fn default() -> Self {
        Self::new(RX_BUFFER)
    }
}

impl Flow {
    /// A counter for a receive buffer of `capacity` bytes.
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity,
            in_flight: VecDeque::new(),
            bytes: 0,
            next_seq: 1,
        }
    }

    /// True if a line of `len` bytes (line end included) fits now.
    pub fn fits(&self, len: usize) -> bool {
        self.bytes + len <= self.capacity
    }

    /// True if a line of `len` bytes could ever fit (the buffer is not too small for it).
    pub fn can_ever_fit(&self, len: usize) -> bool {
        len <= self.capacity
    }

    /// Records a line of `len` bytes as sent and returns its sequence number, or `None` if it
    /// does not fit (nothing recorded).
    pub fn push(&mut self, len: usize) -> Option<u64> {
        if !self.fits(len) {
            return None;
        }
        let seq = self.next_seq;
        self.next_seq += 1;
        self.in_flight.push_back((seq, len));
        self.bytes += len;
        Some(seq)
    }

    /// An `ok` or `error:N` arrived: frees the oldest line and returns its sequence number
    /// (`None` for a reply nobody waits for).
    pub fn pop(&mut self) -> Option<u64> {
        let (seq, len) = self.in_flight.pop_front()?;
        self.bytes -= len;
        Some(seq)
    }

    /// Forgets every line in flight (after a reset or a resynchronisation the controller's
    /// buffer is empty). Sequence numbers keep counting up.
    pub fn clear(&mut self) {
        self.in_flight.clear();
        self.bytes = 0;
    }

    /// Bytes sent but not yet answered.
    pub fn bytes_in_flight(&self) -> usize {
        self.bytes
    }

    /// Lines sent but not yet answered.
    pub fn lines_in_flight(&self) -> usize {
        self.in_flight.len()
    }

    /// True if the line with `seq` is still waiting for its reply.
    pub fn is_pending(&self, seq: u64) -> bool {
        self.in_flight.iter().any(|(s, _)| *s == seq)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_bytes_against_the_127_byte_buffer() {
        let mut f = Flow::default();
        let a = f.push(100).unwrap();
        assert!(f.fits(27));
        assert!(!f.fits(28));
        assert_eq!(f.push(28), None);
        assert_eq!(f.bytes_in_flight(), 100);
        let b = f.push(27).unwrap();
        assert!(b > a);
        assert_eq!(f.bytes_in_flight(), 127);
        assert!(!f.fits(1));
        assert_eq!(f.pop(), Some(a));
        assert!(f.fits(100) && !f.fits(101));
        assert!(f.is_pending(b) && !f.is_pending(a));
        assert_eq!(f.pop(), Some(b));
        assert_eq!(f.pop(), None, "a stray ok frees nothing");
        assert_eq!(f.bytes_in_flight(), 0);
    }

    #[test]
    fn clear_empties_but_sequence_keeps_counting() {
        let mut f = Flow::default();
        let a = f.push(10).unwrap();
        f.push(10).unwrap();
        f.clear();
        assert_eq!(f.lines_in_flight(), 0);
        assert!(f.fits(127));
        assert!(!f.can_ever_fit(128));
        assert!(f.push(5).unwrap() > a + 1);
    }
}
