use bevworld_types::{bytes_digest, file_digest};

#[test]
fn the_file_digest_is_fnv1a_64() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("a.txt");
    std::fs::write(&path, b"a").expect("write");
    // FNV-1a 64 of "a", from the reference tables.
    assert_eq!(file_digest(&path).expect("digest"), "af63dc4c8601ec8c");
}

#[test]
fn one_flipped_bit_changes_the_digest() {
    let bytes = b"weights".to_vec();
    let mut flipped = bytes.clone();
    flipped[3] ^= 1;
    assert_ne!(bytes_digest(&bytes), bytes_digest(&flipped));
    // The empty input hashes to the FNV offset basis.
    assert_eq!(bytes_digest(&[]), "cbf29ce484222325");
}
