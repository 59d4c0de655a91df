//! Panics of third-party decoders, caught. The exr crate panics on some corrupt compressed
//! blocks instead of returning an error; vkshade calls such decoders through [`catch`],
//! which turns the panic into an `Err` with its message. While a decoder runs inside it,
//! [`active`] is true on that thread, so a program's panic hook can stay quiet about a panic
//! that is about to be caught (`vkshade`'s does; the default hook would print it and a
//! backtrace before the clean error). Decoders that run inside must do so on the calling
//! thread (the EXR reader decodes on one thread).

use std::cell::Cell;
use std::panic::{AssertUnwindSafe, catch_unwind};

thread_local! {
    static DEPTH: Cell<u32> = const { Cell::new(0) };
}

/// Whether this thread is inside [`catch`] (a panic now will be caught and reported as an
/// error).
pub fn active() -> bool {
    DEPTH.with(|d| d.get() > 0)
}

/// Runs `f`, returning its result, or the panic's message when it panics.
pub fn catch<T>(f: impl FnOnce() -> T) -> std::result::Result<T, String> {
    struct Guard;
    impl Drop for Guard {
        fn drop(&mut self) {
            DEPTH.with(|d| d.set(d.get().saturating_sub(1)));
        }
    }
    DEPTH.with(|d| d.set(d.get() + 1));
    let _guard = Guard;
    // AssertUnwindSafe: `f` owns or borrows only the decoder's input; after a panic nothing
    // it touched is used again (the caller returns the error).
    catch_unwind(AssertUnwindSafe(f)).map_err(|p| {
        p.downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".into())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_becomes_its_message_and_the_scope_ends() {
        assert!(!active());
        assert_eq!(catch(|| 7), Ok(7));
        let e = catch(|| -> u32 {
            assert!(active());
            panic!("capacity overflow")
        });
        assert_eq!(e, Err("capacity overflow".to_string()));
        assert!(!active(), "the scope ends after a panic too");
        let n = 3usize;
        let e = catch(|| -> u32 { panic!("{n} bad blocks") });
        assert_eq!(e, Err("3 bad blocks".to_string()));
    }
}
