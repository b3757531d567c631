//! [`NdVec`]: a variable array of several dimensions, what an IPC format
//! writes `<T:k1,k2,…>` (a struct field whose element count is the product
//! of other fields of the struct).
//!
//! Its shape and its elements always agree, so the derive can write the
//! size fields from the shape, as it writes a `Vec`'s count field from its
//! length, and encoding stays infallible.

use core::fmt;
use core::ops::{Index, IndexMut};

/// The most elements (and the largest dimension) an IPC variable array can
/// have: its count is a C `int`.
pub const MAX_ELEMENTS: usize = i32::MAX as usize;

/// A variable array of `N` dimensions, stored flat in row-major order (the
/// last index varies fastest, as in C and as IPC sends it).
///
/// A field of this type with `#[ipc(len = "rows, cols")]` is the IPC format
/// `<T:k1,k2>`: on encode the size fields are written from [`shape`], on
/// decode the shape comes from the size fields and must hold exactly the
/// elements that came.
///
/// ```
/// use courier_wire::{Matrix, NdVec};
///
/// let m = Matrix::new([2, 3], vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0])?;
/// assert_eq!(m.shape(), [2, 3]);
/// assert_eq!(m[[1, 0]], 4.0);
/// assert_eq!(m.row(1), Some(&[4.0, 5.0, 6.0][..]));
///
/// // the shape must hold exactly the elements given
/// let err = NdVec::<u8, 3>::new([2, 2, 2], vec![0; 7]).unwrap_err();
/// assert_eq!(err.to_string(), "shape [2, 2, 2] holds 8 elements, but 7 were given");
/// # Ok::<(), courier_wire::ShapeError>(())
/// ```
///
/// [`shape`]: NdVec::shape
#[derive(Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NdVec<T, const N: usize> {
    shape: [usize; N],
    data: Vec<T>,
}

/// A two-dimensional [`NdVec`] (`<T:rows,cols>`).
pub type Matrix<T> = NdVec<T, 2>;

/// Why a shape and its elements cannot make an [`NdVec`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ShapeError {
    /// The shape's element count differs from the number of elements.
    #[error("shape {shape:?} holds {expected} elements, but {found} were given")]
    Length {
        /// The shape.
        shape: Vec<u64>,
        /// Its product.
        expected: u64,
        /// Elements given (or received).
        found: usize,
    },
    /// A dimension is negative (a size field received from a peer).
    #[error("dimension {dim} of the shape is {value}: a size cannot be negative")]
    Negative {
        /// Which dimension, from 1.
        dim: usize,
        /// Its value.
        value: i128,
    },
    /// The shape holds more than [`MAX_ELEMENTS`] elements, or a dimension
    /// exceeds it.
    #[error(
        "shape {shape:?} is too large: an IPC variable array holds at most 2147483647 elements"
    )]
    TooLarge {
        /// The shape (dimensions beyond `u64` saturate).
        shape: Vec<u64>,
    },
    /// Rows of a matrix given as vectors differ in length.
    #[error(
        "row {row} has {found} elements, but row 0 has {expected}: a matrix's rows are all as long"
    )]
    Ragged {
        /// The first row of another length.
        row: usize,
        /// Its length.
        found: usize,
        /// The length of row 0.
        expected: usize,
    },
}

fn shape_u64(shape: &[usize]) -> Vec<u64> {
    shape.iter().map(|&d| d as u64).collect()
}

/// The number of elements `shape` holds, or why it cannot be an IPC array.
fn element_count(shape: &[usize]) -> Result<usize, ShapeError> {
    let too_large = || ShapeError::TooLarge {
        shape: shape_u64(shape),
    };
    if shape.iter().any(|&d| d > MAX_ELEMENTS) {
        return Err(too_large());
    }
    if shape.contains(&0) {
        return Ok(0);
    }
    let mut n: usize = 1;
    for &d in shape {
        n = n
            .checked_mul(d)
            .filter(|&n| n <= MAX_ELEMENTS)
            .ok_or_else(too_large)?;
    }
    Ok(n)
}

impl<T, const N: usize> NdVec<T, N> {
    /// `NdVec<T, 0>` does not compile: a shape needs a dimension.
    const HAS_DIMENSIONS: () = assert!(N >= 1, "an NdVec needs at least one dimension");

    /// An array of `shape` holding `data` in row-major order; `data` must
    /// have exactly as many elements as the shape holds, and no more than
    /// [`MAX_ELEMENTS`].
    pub fn new(shape: [usize; N], data: Vec<T>) -> Result<Self, ShapeError> {
        let () = Self::HAS_DIMENSIONS;
        let expected = element_count(&shape)?;
        if expected != data.len() {
            return Err(ShapeError::Length {
                shape: shape_u64(&shape),
                expected: expected as u64,
                found: data.len(),
            });
        }
        Ok(NdVec { shape, data })
    }

    /// An array of `shape` with every element `value`.
    pub fn filled(shape: [usize; N], value: T) -> Result<Self, ShapeError>
    where
        T: Clone,
    {
        let () = Self::HAS_DIMENSIONS;
        let n = element_count(&shape)?;
        Ok(NdVec {
            shape,
            data: vec![value; n],
        })
    }

    /// An array of `shape` whose element at each index is `f(index)`,
    /// called in row-major order.
    pub fn from_fn(
        shape: [usize; N],
        mut f: impl FnMut([usize; N]) -> T,
    ) -> Result<Self, ShapeError> {
        let () = Self::HAS_DIMENSIONS;
        let n = element_count(&shape)?;
        let mut data = Vec::with_capacity(n);
        let mut index = [0usize; N];
        for _ in 0..n {
            data.push(f(index));
            // the next index, last dimension fastest
            for d in (0..N).rev() {
                index[d] += 1;
                if index[d] < shape[d] {
                    break;
                }
                index[d] = 0;
            }
        }
        Ok(NdVec { shape, data })
    }

    /// An array of shape `[0; N]` (no elements).
    pub fn empty() -> Self {
        let () = Self::HAS_DIMENSIONS;
        NdVec {
            shape: [0; N],
            data: Vec::new(),
        }
    }

    /// The size of each dimension.
    pub fn shape(&self) -> [usize; N] {
        self.shape
    }

    /// The number of elements (the product of the shape).
    pub fn len(&self) -> usize {
        self.data.len()
    }

    /// Whether there are no elements.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// The elements, row-major.
    pub fn as_slice(&self) -> &[T] {
        &self.data
    }

    /// The elements, row-major, to change in place (the shape stays).
    pub fn as_mut_slice(&mut self) -> &mut [T] {
        &mut self.data
    }

    /// The elements in row-major order.
    pub fn iter(&self) -> core::slice::Iter<'_, T> {
        self.data.iter()
    }

    /// The shape and the elements.
    pub fn into_parts(self) -> ([usize; N], Vec<T>) {
        (self.shape, self.data)
    }

    /// The elements, row-major.
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// The same elements in another shape holding as many.
    pub fn reshape<const M: usize>(self, shape: [usize; M]) -> Result<NdVec<T, M>, ShapeError> {
        NdVec::new(shape, self.data)
    }

    /// The flat position of `index`, if it is inside the shape.
    fn offset(&self, index: [usize; N]) -> Option<usize> {
        let mut at = 0;
        for (i, d) in index.iter().zip(&self.shape) {
            if i >= d {
                return None;
            }
            at = at * d + i;
        }
        Some(at)
    }

    /// The element at `index`, or `None` outside the shape.
    pub fn get(&self, index: [usize; N]) -> Option<&T> {
        self.offset(index).map(|at| &self.data[at])
    }

    /// The element at `index` to change, or `None` outside the shape.
    pub fn get_mut(&mut self, index: [usize; N]) -> Option<&mut T> {
        self.offset(index).map(|at| &mut self.data[at])
    }
}

impl<T> NdVec<T, 2> {
    /// The number of rows (the first dimension).
    pub fn rows(&self) -> usize {
        self.shape[0]
    }

    /// The number of columns (the second dimension).
    pub fn cols(&self) -> usize {
        self.shape[1]
    }

    /// Row `i`, or `None` past the last row.
    pub fn row(&self, i: usize) -> Option<&[T]> {
        let c = self.shape[1];
        (i < self.shape[0]).then(|| &self.data[i * c..(i + 1) * c])
    }

    /// A matrix from rows that all have `C` elements.
    pub fn from_rows<const C: usize>(rows: Vec<[T; C]>) -> Result<Self, ShapeError> {
        let shape = [rows.len(), C];
        element_count(&shape)?;
        Ok(NdVec {
            shape,
            data: rows.into_iter().flatten().collect(),
        })
    }

    /// A matrix from rows given as vectors, which must all be as long
    /// ([`ShapeError::Ragged`] names the first that is not). No rows make
    /// a 0 × 0 matrix.
    pub fn from_row_vecs(rows: Vec<Vec<T>>) -> Result<Self, ShapeError> {
        let cols = rows.first().map_or(0, Vec::len);
        if let Some((row, r)) = rows.iter().enumerate().find(|(_, r)| r.len() != cols) {
            return Err(ShapeError::Ragged {
                row,
                found: r.len(),
                expected: cols,
            });
        }
        let shape = [rows.len(), cols];
        element_count(&shape)?;
        Ok(NdVec {
            shape,
            data: rows.into_iter().flatten().collect(),
        })
    }

    /// The rows, in order.
    pub fn iter_rows(&self) -> impl ExactSizeIterator<Item = &[T]> + '_ {
        let cols = self.shape[1];
        // a matrix without columns still has its rows (all empty)
        (0..self.shape[0]).map(move |i| &self.data[i * cols..(i + 1) * cols])
    }
}

impl<T, const N: usize> Default for NdVec<T, N> {
    fn default() -> Self {
        Self::empty()
    }
}

impl<T: fmt::Debug, const N: usize> fmt::Debug for NdVec<T, N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("NdVec")
            .field("shape", &self.shape)
            .field("data", &self.data)
            .finish()
    }
}

impl<T, const N: usize> Index<[usize; N]> for NdVec<T, N> {
    type Output = T;

    /// # Panics
    /// If `index` is outside the shape (as slices do); [`NdVec::get`] does not panic.
    fn index(&self, index: [usize; N]) -> &T {
        match self.offset(index) {
            Some(at) => &self.data[at],
            None => panic!("index {index:?} is outside the shape {:?}", self.shape),
        }
    }
}

impl<T, const N: usize> IndexMut<[usize; N]> for NdVec<T, N> {
    fn index_mut(&mut self, index: [usize; N]) -> &mut T {
        match self.offset(index) {
            Some(at) => &mut self.data[at],
            None => panic!("index {index:?} is outside the shape {:?}", self.shape),
        }
    }
}

impl<'a, T, const N: usize> IntoIterator for &'a NdVec<T, N> {
    type Item = &'a T;
    type IntoIter = core::slice::Iter<'a, T>;
    fn into_iter(self) -> Self::IntoIter {
        self.data.iter()
    }
}

impl<T, const N: usize> IntoIterator for NdVec<T, N> {
    type Item = T;
    type IntoIter = std::vec::IntoIter<T>;
    fn into_iter(self) -> Self::IntoIter {
        self.data.into_iter()
    }
}

impl<T, const N: usize> AsRef<[T]> for NdVec<T, N> {
    fn as_ref(&self) -> &[T] {
        &self.data
    }
}

/// A shape received from a peer (size fields of any integer type) with the
/// elements that came: negative or too large dimensions are errors.
pub(crate) fn from_received<T, const N: usize>(
    dims: [i128; N],
    data: Vec<T>,
) -> Result<NdVec<T, N>, ShapeError> {
    let mut shape = [0usize; N];
    for (d, (&v, s)) in dims.iter().zip(&mut shape).enumerate() {
        if v < 0 {
            return Err(ShapeError::Negative {
                dim: d + 1,
                value: v,
            });
        }
        *s = usize::try_from(v).unwrap_or(usize::MAX);
    }
    NdVec::new(shape, data)
}

#[cfg(feature = "serde")]
mod serde_impl {
    use super::NdVec;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    /// `{"shape": [..], "data": [..]}`, checked on the way in.
    #[derive(Serialize, Deserialize)]
    #[serde(rename = "NdVec")]
    struct Repr<D> {
        shape: Vec<usize>,
        data: D,
    }

    impl<T: Serialize, const N: usize> Serialize for NdVec<T, N> {
        fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
            Repr {
                shape: self.shape.to_vec(),
                data: &self.data,
            }
            .serialize(s)
        }
    }

    impl<'de, T: Deserialize<'de>, const N: usize> Deserialize<'de> for NdVec<T, N> {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            let r = Repr::<Vec<T>>::deserialize(d)?;
            let shape: [usize; N] = r.shape.as_slice().try_into().map_err(|_| {
                serde::de::Error::custom(format_args!(
                    "shape has {} dimensions, expected {N}",
                    r.shape.len()
                ))
            })?;
            NdVec::new(shape, r.data).map_err(serde::de::Error::custom)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shape_and_elements_must_agree() {
        assert!(NdVec::<i32, 2>::new([2, 3], vec![0; 6]).is_ok());
        assert_eq!(
            NdVec::<i32, 2>::new([2, 3], vec![0; 5]),
            Err(ShapeError::Length {
                shape: vec![2, 3],
                expected: 6,
                found: 5
            })
        );
        // a zero dimension holds nothing, whatever the others say
        assert_eq!(NdVec::<u8, 2>::new([0, 1 << 30], vec![]).unwrap().len(), 0);
        assert!(matches!(
            NdVec::<u8, 2>::new([1 << 16, 1 << 16], vec![]),
            Err(ShapeError::TooLarge { .. })
        ));
        assert!(matches!(
            NdVec::<u8, 2>::new([0, MAX_ELEMENTS + 1], vec![]),
            Err(ShapeError::TooLarge { .. })
        ));
    }

    #[test]
    fn indexing_is_row_major() {
        let a = NdVec::from_fn([2, 3, 4], |[i, j, k]| i * 100 + j * 10 + k).unwrap();
        assert_eq!(a.len(), 24);
        assert_eq!(&a.as_slice()[..5], &[0, 1, 2, 3, 10]);
        assert_eq!(a[[1, 2, 3]], 123);
        assert_eq!(a.get([1, 3, 0]), None);
        assert_eq!(a.get([2, 0, 0]), None);
        let m = Matrix::from_rows(vec![[1, 2], [3, 4], [5, 6]]).unwrap();
        assert_eq!((m.rows(), m.cols()), (3, 2));
        assert_eq!(m.row(2), Some(&[5, 6][..]));
        assert_eq!(m.row(3), None);
        let rows: Vec<&[i32]> = m.iter_rows().collect();
        assert_eq!(rows, [&[1, 2][..], &[3, 4], &[5, 6]]);
        assert_eq!(
            Matrix::from_row_vecs(vec![vec![1, 2], vec![3, 4], vec![5, 6]]).unwrap(),
            m
        );
        assert_eq!(
            Matrix::from_row_vecs(vec![vec![1, 2], vec![3]])
                .unwrap_err()
                .to_string(),
            "row 1 has 1 elements, but row 0 has 2: a matrix's rows are all as long"
        );
        let empty = Matrix::<u8>::from_row_vecs(vec![vec![], vec![]]).unwrap();
        assert_eq!((empty.shape(), empty.iter_rows().count()), ([2, 0], 2));
        assert_eq!(Matrix::<u8>::from_row_vecs(vec![]).unwrap().shape(), [0, 0]);
        let mut m = m.reshape([2, 3]).unwrap();
        m[[1, 2]] = 60;
        assert_eq!(m.into_vec(), vec![1, 2, 3, 4, 5, 60]);
    }

    #[test]
    fn received_shapes_are_checked() {
        assert_eq!(
            from_received::<u8, 2>([2, -1], vec![]),
            Err(ShapeError::Negative { dim: 2, value: -1 })
        );
        assert!(matches!(
            from_received::<u8, 2>([1 << 40, 0], vec![]),
            Err(ShapeError::TooLarge { .. })
        ));
        assert_eq!(from_received([2, 2], vec![1, 2, 3, 4]).unwrap()[[1, 0]], 3);
    }

    #[cfg(feature = "serde")]
    #[test]
    fn serde_checks_the_shape_on_the_way_in() {
        let m = Matrix::new([2, 1], vec![1u8, 2]).unwrap();
        let json = serde_json::to_string(&m).unwrap();
        assert_eq!(json, r#"{"shape":[2,1],"data":[1,2]}"#);
        assert_eq!(serde_json::from_str::<Matrix<u8>>(&json).unwrap(), m);
        let e = serde_json::from_str::<Matrix<u8>>(r#"{"shape":[2,2],"data":[1,2]}"#).unwrap_err();
        assert!(
            e.to_string()
                .contains("shape [2, 2] holds 4 elements, but 2 were given"),
            "{e}"
        );
        let e = serde_json::from_str::<Matrix<u8>>(r#"{"shape":[2],"data":[1,2]}"#).unwrap_err();
        assert!(
            e.to_string().contains("shape has 1 dimensions, expected 2"),
            "{e}"
        );
    }

    #[test]
    #[should_panic(expected = "index [0, 2] is outside the shape [1, 2]")]
    fn index_outside_the_shape_panics_with_both() {
        let m = Matrix::new([1, 2], vec![1, 2]).unwrap();
        let _ = m[[0, 2]];
    }
}
