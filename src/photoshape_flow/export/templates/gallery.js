(function(){
  const table=document.getElementById('photoshapes'); if(!table) return;
  const body=table.tBodies[0]; const rows=()=>Array.from(body.rows);
  function value(row,key,type){const v=row.dataset[key];
    if(v===undefined||v==='') return null; return type==='num'?parseFloat(v):v.toLowerCase();}
  function sortBy(th,dir){const key=th.dataset.key,type=th.dataset.type;
    const sorted=rows().sort((a,b)=>{const x=value(a,key,type),y=value(b,key,type);
      if(x===null&&y===null) return 0; if(x===null) return 1; if(y===null) return -1;
      return (x<y?-1:x>y?1:0)*dir;});
    sorted.forEach(r=>body.appendChild(r));
    table.querySelectorAll('th').forEach(h=>h.classList.remove('asc','desc'));
    th.classList.add(dir>0?'asc':'desc'); th.dataset.dir=dir;}
  table.querySelectorAll('th[data-key]').forEach(th=>th.addEventListener('click',()=>{
    const dir=th.dataset.dir==='1'?-1:(th.dataset.dir==='-1'?1:parseInt(th.dataset.first||'1'));
    sortBy(th,dir);}));
  const filter=document.getElementById('grade-filter'), text=document.getElementById('text-filter');
  // "ungraded" keeps the rows without a grade; ?grade=LABEL or ?grade=ungraded opens the page filtered
  const graded=(r,g)=>g==='ungraded'?!r.dataset.grade:r.dataset.grade===g;
  function apply(){const g=filter.value,t=text.value.toLowerCase();let shown=0;
    rows().forEach(r=>{const ok=(!g||graded(r,g))&&(!t||r.textContent.toLowerCase().includes(t));
      r.hidden=!ok; shown+=ok;}); document.getElementById('count').textContent=shown;}
  function remember(){try{const url=new URL(location.href);
    if(filter.value) url.searchParams.set('grade',filter.value); else url.searchParams.delete('grade');
    history.replaceState(null,'',url);}catch(e){/* a file:// page may refuse: the filter still works */}}
  const asked=new URLSearchParams(location.search).get('grade');
  if(asked&&Array.from(filter.options).some(o=>o.value===asked)) filter.value=asked;
  filter.addEventListener('change',()=>{apply();remember();}); text.addEventListener('input',apply);
  apply();
  const initial=table.querySelector('th[data-key="score"]'); if(initial) sortBy(initial,-1);
})();
